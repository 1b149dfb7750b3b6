"""Environments: the seed's Reach1D and the batched interface the collector drives."""

from __future__ import annotations

import dataclasses
from functools import partial

from cmdp_rl.config import EnvConfig, GymEnvConfig, VelocityEnvConfig
from cmdp_rl.envs.gym_cost import make_cost_env
from cmdp_rl.envs.reach1d import Reach1D
from cmdp_rl.envs.reach1d_torch import NoiseSource, TorchNoise, TorchReach1D
from cmdp_rl.envs.vector import GymVecEnv, Step, VecEnv
from cmdp_rl.envs.velocity import make_velocity_env

REACH1D_ID = "cmdp_rl/Reach1D-v0"


def reach1d_kwargs(cfg: EnvConfig) -> dict:
    """The Reach1D constructor arguments an :class:`EnvConfig` asks for."""
    return dict(
        obs_noise=cfg.obs_noise, wall_x=cfg.wall_x, max_steps=cfg.max_steps, goal=cfg.goal,
        wall=cfg.wall, start=cfg.start, probe=cfg.probe,
    )


def make_env(
    cfg: EnvConfig | VelocityEnvConfig | GymEnvConfig, num_envs: int | None = None, device: str = "cpu"
) -> VecEnv:
    """Build the batched env a config names (``num_envs`` overrides ``cfg.num_envs``).

    ``device`` is where the env's tensors live: the torch backend steps there; the gym backend
    steps on the CPU and moves its tensors there.
    """
    n = cfg.num_envs if num_envs is None else num_envs
    if cfg.name == "reach1d" and cfg.backend == "gym":
        return GymVecEnv(partial(Reach1D, **reach1d_kwargs(cfg)), n, device=device)
    if cfg.name == "reach1d" and cfg.backend == "torch":
        return TorchReach1D(n, **reach1d_kwargs(cfg), stagger=cfg.stagger, device=device)
    if cfg.name == "velocity" and cfg.backend == "gym":
        return GymVecEnv(partial(make_velocity_env, cfg.task, cfg.velocity_threshold, cfg.max_steps), n, device=device)
    if cfg.name == "gym" and cfg.backend == "gym":
        return GymVecEnv(partial(make_cost_env, cfg.id, cfg.step_api, cfg.max_steps, **cfg.kwargs), n, device=device)
    raise ValueError(f"env: no implementation for name={cfg.name!r} backend={cfg.backend!r}")


def make_eval_env(
    cfg: EnvConfig | VelocityEnvConfig | GymEnvConfig, num_envs: int | None = None, device: str = "cpu"
) -> VecEnv:
    """The env evaluation runs on: ``cfg``'s, with whole episodes only (no staggered start)."""
    if getattr(cfg, "stagger", False):
        cfg = dataclasses.replace(cfg, stagger=False)
    return make_env(cfg, num_envs, device)


__all__ = [
    "REACH1D_ID", "GymVecEnv", "NoiseSource", "Reach1D", "Step", "TorchNoise", "TorchReach1D", "VecEnv",
    "make_cost_env", "make_env", "make_eval_env", "make_velocity_env", "reach1d_kwargs",
]
