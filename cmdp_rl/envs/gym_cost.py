"""Any registered gymnasium env that reports a cost, for ``env=gym env.id=<id>`` (``"module:EnvId-v0"`` imports
``module`` first, so that it can register its envs, as ``gymnasium.make`` does).

``env.step_api=five`` (gymnasium's step, the cost in ``info["cost"]``): built by ``gymnasium.make``. ``six``
(Safety-Gymnasium's ``(obs, reward, cost, terminated, truncated, info)``, which gymnasium's wrappers cannot unpack):
built from its registered entry point, converted by :class:`SixValueStep`, given gymnasium's ``TimeLimit``."""

from __future__ import annotations

import importlib
from dataclasses import field
from functools import partial
from typing import Annotated, Any, Literal, Optional

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import load_env_creator
from gymnasium.wrappers import TimeLimit

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import ConfigError, Field, NonNegativeInt, PositiveInt, options
from cmdp_rl.envs.contract import EnvContractError
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.vector import GymVecEnv, VecEnv


class SixValueStep(gym.Wrapper):
    """A six-value step ``(obs, reward, cost, terminated, truncated, info)`` as gymnasium's five (cost in info)."""

    def step(self, action):
        out = self.env.step(action)
        if len(out) != 6:
            raise EnvContractError(
                f"env.step_api=six: the env's step returned {len(out)} values, expected 6 "
                "(obs, reward, cost, terminated, truncated, info); use env.step_api=five for gymnasium's protocol"
            )
        obs, reward, cost, terminated, truncated, info = out
        info = dict(info)
        # One number (one constraint) stays a float; a vector of K costs stays a vector.
        info["cost"] = float(cost) if np.ndim(cost) == 0 else np.asarray(cost, dtype=np.float64)
        return obs, reward, terminated, truncated, info


class RequireCost(gym.Wrapper):
    """Fails on the first step without ``info["cost"]``: such an env would train as if perfectly safe."""

    def __init__(self, env: gym.Env, env_id: str) -> None:
        super().__init__(env)
        self.env_id = env_id

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if "cost" not in info:
            raise EnvContractError(
                f"env.id={self.env_id}: the env's step reports no info['cost'] (keys: {sorted(info)}); "
                "env=gym needs an env that reports its cost there, or a six-value step with env.step_api=six"
            )
        return obs, reward, terminated, truncated, info


def _registered(env_id: str):
    """``env_id``'s gymnasium spec and constructor (its module imported first, if it names one)."""
    module, _, name = env_id.rpartition(":")
    if module:
        importlib.import_module(module)
    spec = gym.spec(name)
    return spec, load_env_creator(spec.entry_point) if isinstance(spec.entry_point, str) else spec.entry_point


def make_cost_env(env_id: str, step_api: str = "five", max_steps: int = 0, **kwargs: Any) -> gym.Env:
    """One env of ``env_id`` reporting its cost in ``info["cost"]``; ``max_steps``: the time limit
    (0: the registered one, if any); ``kwargs`` go to the env's constructor."""
    spec, creator = _registered(env_id)
    if step_api == "five":
        return RequireCost(gym.make(spec.id, max_episode_steps=max_steps or None, **kwargs), env_id)
    if step_api == "six":
        env = SixValueStep(creator(**{**spec.kwargs, **kwargs}))
        limit = max_steps or spec.max_episode_steps
        return TimeLimit(env, limit) if limit else env
    raise ValueError(f"env.step_api must be 'five' or 'six', got {step_api!r}")


@options
class GymEnvConfig(EnvOptions):
    """``env=gym``: any registered gymnasium env that reports cost, in ``info["cost"]`` (five-value
    step) or as the third value of a Safety-Gymnasium six-value step."""

    name: str = "gym"
    backend: Literal["gym"] = "gym"
    num_envs: PositiveInt = 8
    id: Annotated[str, Field(pattern=r"\S", description="a registered gymnasium id, e.g. env.id=MyCostEnv-v0")] = ""
    step_api: Literal["five", "six"] = "five"
    max_steps: Annotated[NonNegativeInt, Field(description="an integer >= 0 (0: the registered limit)")] = 0
    kwargs: Annotated[dict, Field(description="a mapping of constructor arguments")] = field(default_factory=dict)
    # The K costs' names in info["cost"]'s order; None: the env's own, else cost_0 ... cost_{K-1}.
    cost_names: Annotated[
        Optional[list[Annotated[str, Field(pattern=r"^[^/\s]+$")]]],
        Field(description="null or a list of distinct names without '/' or spaces, one per cost"),
    ] = None

    def check(self, run: Any) -> None:
        names = self.cost_names
        if names is not None and (not names or len(set(names)) != len(names)):
            raise ConfigError(f"env.cost_names must be a non-empty list of distinct names, got {names!r}")

    def render_env(self) -> gym.Env:
        """One env of this id drawing ``rgb_array`` frames (for video), if its class offers them."""
        _, creator = _registered(self.id)
        modes = list(getattr(creator, "metadata", {}).get("render_modes", []))
        if "rgb_array" not in modes:
            raise ConfigError(
                f"video: env=gym env.id={self.id} cannot render rgb_array frames (its render modes: {modes})"
            )
        return make_cost_env(self.id, self.step_api, self.max_steps, **{"render_mode": "rgb_array", **self.kwargs})


def make_gym_vec_env(cfg: GymEnvConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    return GymVecEnv(
        partial(make_cost_env, cfg.id, cfg.step_api, cfg.max_steps, **cfg.kwargs),
        num_envs,
        device=device,
        env_id=cfg.id,
        cost_names=cfg.cost_names,
    )


register("env", "gym", GymEnvConfig, make_gym_vec_env)
