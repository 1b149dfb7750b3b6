"""Saving one gymnasium env in the middle of an episode, and restoring it into a fresh copy.

Gymnasium has no API for this, and pickling does not do it (its MuJoCo envs pickle their constructor
arguments only, ``EzPickle``). So we save what an env's future depends on, layer by layer: each
wrapper's plain attributes (``TimeLimit``'s elapsed steps); the base env's own ``state_dict()`` where
it has one (Reach1D), else its random generator's state, its plain attributes and, for a MuJoCo
env, its ``MjData`` as arrays. Every value saved is a number, a string, an array or a plain container
of them: a checkpoint holds no pickled object (docs/checkpoints.md). Configuration (spaces, specs,
the MuJoCo model, renderers) is skipped; any other attribute (a Box2D world, say) raises
``NotImplementedError`` naming it rather than save a state that would resume inexactly.
"""

from __future__ import annotations

import collections
import copy
from typing import Any

import gymnasium as gym
import numpy as np

# Attributes that hold configuration or plumbing, never episode state.
_SKIPPED_NAMES = set(
    "env spec metadata _saved_kwargs _ezpickle_args _ezpickle_kwargs _cached_spec _metadata _action_space "
    "_observation_space _np_random_seed mujoco_renderer screen clock model np_random _np_random".split()
)


def _plain(value: Any) -> bool:
    """Numbers, strings, arrays and containers of them: state that copies by value."""
    if value is None or isinstance(value, (bool, int, float, str, np.ndarray, np.generic)):
        return True
    if isinstance(value, (list, tuple, collections.deque)):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, (str, int)) and _plain(v) for k, v in value.items())
    return False


def _static(value: Any) -> bool:
    return isinstance(value, (gym.spaces.Space, gym.envs.registration.EnvSpec))


def _attributes(obj: Any, where: str) -> dict[str, Any]:
    out = {}
    for name, value in vars(obj).items():
        if name in _SKIPPED_NAMES or _static(value):
            continue
        if name == "data" and _is_mujoco_data(value):
            continue  # saved whole, below
        if not _plain(value):
            raise NotImplementedError(
                f"{where} holds {name!r} ({type(value).__name__}), which cmdp_rl cannot save, so a run on it "
                "cannot resume exactly"
            )
        out[name] = copy.deepcopy(value)  # detached from the live env
    return out


def _is_mujoco_data(value: Any) -> bool:
    return type(value).__module__.startswith("mujoco") and type(value).__name__ == "MjData"


def mujoco_data_state(model: Any, data: Any) -> dict[str, Any]:
    """An ``MjData`` as arrays: MuJoCo's integration state (``mj_getState``) and every array of the
    data whose size the model fixes. The second part matters: after ``mj_step`` the derived fields
    (body positions, contact forces) are those of the last substep's start, and an env may read them
    before its next step (gymnasium's Ant does), so ``mj_forward`` would not continue the episode bit
    for bit. Arrays sized by the step's contacts are left out: the next step recomputes them."""
    import mujoco

    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    integration = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, integration, spec)
    fresh = mujoco.MjData(model)  # the sizes the model fixes: those of a new data
    arrays = {}
    for name in dir(data):
        if name.startswith("_"):
            continue
        value = getattr(data, name, None)
        if isinstance(value, np.ndarray) and value.flags.writeable and value.size:
            if getattr(fresh, name).shape == value.shape:
                arrays[name] = value.copy()
    return {"integration": integration, "arrays": arrays}


def load_mujoco_data_state(model: Any, data: Any, state: dict[str, Any]) -> None:
    """Restore :func:`mujoco_data_state`'s ``state`` into ``data`` (of the same model)."""
    import mujoco

    mujoco.mj_setState(model, data, state["integration"], mujoco.mjtState.mjSTATE_INTEGRATION)
    for name, value in state["arrays"].items():
        getattr(data, name)[...] = value


def env_state(env: gym.Env) -> dict[str, Any]:
    """The state of ``env`` (wrappers included) that :func:`load_env_state` restores."""
    wrappers, base = [], env
    while isinstance(base, gym.Wrapper):
        wrappers.append(_attributes(base, type(base).__name__))
        base = base.env
    state: dict[str, Any] = {"base_type": type(base).__name__, "wrappers": wrappers}
    if hasattr(base, "state_dict"):
        state["own"] = base.state_dict()
        return state
    rng = getattr(base, "_np_random", None)
    state["np_random"] = None if rng is None else rng.bit_generator.state
    state["attributes"] = _attributes(base, type(base).__name__)
    data = getattr(base, "data", None)
    if _is_mujoco_data(data):
        state["mujoco"] = mujoco_data_state(base.model, data)
    return state


def load_env_state(env: gym.Env, state: dict[str, Any]) -> None:
    """Restore ``state`` (from :func:`env_state` on an env built the same way) into ``env``."""
    wrappers, base = [], env
    while isinstance(base, gym.Wrapper):
        wrappers.append(base)
        base = base.env
    if type(base).__name__ != state["base_type"] or len(wrappers) != len(state["wrappers"]):
        raise ValueError(f"env: saved state is of {state['base_type']}, this env is {type(base).__name__}")
    for wrapper, attrs in zip(wrappers, state["wrappers"]):
        for name, value in attrs.items():
            setattr(wrapper, name, copy.deepcopy(value))
    if "own" in state:
        base.load_state_dict(state["own"])
        return
    if state["np_random"] is not None:
        base.np_random.bit_generator.state = state["np_random"]  # creates the generator if need be
    for name, value in state["attributes"].items():
        setattr(base, name, copy.deepcopy(value))
    if "mujoco" in state:
        load_mujoco_data_state(base.model, base.data, state["mujoco"])
