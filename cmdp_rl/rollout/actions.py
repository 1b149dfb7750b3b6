"""The action spaces the toolkit supports, and how one env's action is stored, a flat vector ``[d]``:
``Box`` (any shape): its ``prod(shape)`` floats; ``Discrete(n, start)``: one int64 index in ``[0, n)``
(``start`` added for the env); ``MultiDiscrete``: one index per component; hybrid, a ``Tuple`` or ``Dict``
of one ``Discrete`` skill and one float ``Box`` of its parameters: floats ``[skill, params...]``
(:class:`Hybrid`).
"""

from __future__ import annotations

from typing import NamedTuple

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from cmdp_rl.config.validation import ConfigError

SUPPORTED = "Box, Discrete, MultiDiscrete, Tuple/Dict of one Discrete and one Box (hybrid)"


class UnsupportedActionSpace(ConfigError):
    """An env's action space no policy head handles (one line, exit status 2 in ``train.py``)."""


class Hybrid(NamedTuple):
    """A hybrid space's parts: ``skills`` choices, the parameters' box, and where each sits in the space."""

    skills: int
    start: int
    box: spaces.Box
    skill_at: int | str
    box_at: int | str


def hybrid(space: gym.Space) -> Hybrid | None:
    """The parts of a ``Tuple``/``Dict`` of one ``Discrete`` and one float ``Box`` (either order), else None."""
    if isinstance(space, spaces.Tuple):
        items = list(enumerate(space.spaces))
    elif isinstance(space, spaces.Dict):
        items = list(space.spaces.items())
    else:
        return None
    skill = [(at, s) for at, s in items if isinstance(s, spaces.Discrete)]
    box = [(at, s) for at, s in items if isinstance(s, spaces.Box) and np.issubdtype(s.dtype, np.floating)]
    if len(items) != 2 or len(skill) != 1 or len(box) != 1:
        return None
    (skill_at, d), (box_at, b) = skill[0], box[0]
    return Hybrid(int(d.n), int(d.start), b, skill_at, box_at)


def check_action_space(space: gym.Space, env_id: str = "env") -> None:
    """Raise :class:`UnsupportedActionSpace` unless the toolkit can act in ``space``."""
    if hybrid(space) is not None:
        return
    if not isinstance(space, (spaces.Box, spaces.Discrete, spaces.MultiDiscrete)):
        raise UnsupportedActionSpace(f"env {env_id}: action space {space} is not supported; supported: {SUPPORTED}")
    if isinstance(space, spaces.Box) and not np.issubdtype(space.dtype, np.floating):
        raise UnsupportedActionSpace(
            f"env {env_id}: action space {space} is not supported: a Box of integers "
            f"(dtype {space.dtype}); use Discrete or MultiDiscrete"
        )


def is_discrete(space: gym.Space) -> bool:
    return isinstance(space, (spaces.Discrete, spaces.MultiDiscrete))


def action_dim(space: gym.Space) -> int:
    """Entries of one stored action."""
    if isinstance(space, spaces.Discrete):
        return 1
    if isinstance(space, spaces.MultiDiscrete):
        return int(space.nvec.size)
    parts = hybrid(space)
    if parts is not None:
        return 1 + int(np.prod(parts.box.shape))
    return int(np.prod(space.shape))


def action_bounds(space: gym.Space) -> tuple[torch.Tensor, torch.Tensor]:
    """Each stored entry's range ``[d]``: a box's bounds, an index's ``[0, n - 1]``, a hybrid's skill then box."""
    parts = hybrid(space)
    if parts is not None:
        low, high = action_bounds(parts.box)
        return torch.cat([torch.zeros(1), low]), torch.cat([torch.tensor([parts.skills - 1.0]), high])
    if is_discrete(space):
        return torch.zeros(action_dim(space)), torch.tensor(categories(space), dtype=torch.float32) - 1
    low = torch.as_tensor(space.low, dtype=torch.float32).reshape(-1)
    return low, torch.as_tensor(space.high, dtype=torch.float32).reshape(-1)


def categories(space: gym.Space) -> tuple[int, ...]:
    """The number of choices of each component of a discrete action (``()`` for a box)."""
    if isinstance(space, spaces.Discrete):
        return (int(space.n),)
    if isinstance(space, spaces.MultiDiscrete):
        return tuple(int(n) for n in space.nvec.reshape(-1))
    return ()


def to_env(action: torch.Tensor, space: gym.Space) -> np.ndarray:
    """``[N, d]`` stored actions -> what a gymnasium vector env of ``space`` steps on."""
    act = action.detach().cpu().numpy()
    n = act.shape[0]
    if isinstance(space, spaces.Discrete):
        return act[:, 0].astype(space.dtype, copy=False) + space.start
    if isinstance(space, spaces.MultiDiscrete):
        return act.reshape(n, *space.shape).astype(space.dtype, copy=False) + space.start
    parts = hybrid(space)
    if parts is not None:  # gymnasium's batched Tuple is a tuple of batched parts, its Dict a dict
        skill = act[:, 0].round().astype(np.int64) + parts.start
        params = act[:, 1:].reshape(n, *parts.box.shape).astype(parts.box.dtype, copy=False)
        if isinstance(space, spaces.Dict):
            return {parts.skill_at: skill, parts.box_at: params}
        return (skill, params) if parts.skill_at == 0 else (params, skill)
    # The env's own dtype (float32 for Reach1D): a float64 action could land exactly on the
    # seed's wall, where the strict crossing test lets it through at no cost.
    return act.reshape(n, *space.shape).astype(space.dtype, copy=False)


def uniform_actions(space: gym.Space, n: int, device: torch.device | str) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` stored actions uniform on ``space`` (finite bounds) and their log-density ``[n]``: a warm-up."""
    if isinstance(space, spaces.Box):
        low = torch.as_tensor(space.low, dtype=torch.float32, device=device).reshape(-1)
        high = torch.as_tensor(space.high, dtype=torch.float32, device=device).reshape(-1)
        action = low + (high - low) * torch.rand(n, low.numel(), device=device)
        return action, (-(high - low).log().sum()).expand(n)
    parts = hybrid(space)
    if parts is not None:
        skill, skill_logp = uniform_actions(spaces.Discrete(parts.skills), n, device)
        params, params_logp = uniform_actions(parts.box, n, device)
        return torch.cat([skill.float(), params], dim=-1), skill_logp + params_logp
    sizes = torch.tensor(categories(space), device=device)
    action = (torch.rand(n, sizes.numel(), device=device) * sizes).long()
    return action, (-sizes.float().log().sum()).expand(n)
