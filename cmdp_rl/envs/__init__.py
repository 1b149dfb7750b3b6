"""Environments: the seed's Reach1D and the batched interface the collector drives."""

from __future__ import annotations

from functools import partial

from cmdp_rl.config import EnvConfig, GymEnvConfig, VelocityEnvConfig
from cmdp_rl.envs.gym_cost import make_cost_env
from cmdp_rl.envs.reach1d import Reach1D
from cmdp_rl.envs.vector import GymVecEnv, Step, VecEnv
from cmdp_rl.envs.velocity import make_velocity_env

REACH1D_ID = "cmdp_rl/Reach1D-v0"


def reach1d_kwargs(cfg: EnvConfig) -> dict:
    """The Reach1D constructor arguments an :class:`EnvConfig` asks for."""
    return dict(
        obs_noise=cfg.obs_noise, wall_x=cfg.wall_x, max_steps=cfg.max_steps, goal=cfg.goal,
        wall=cfg.wall, start=cfg.start, probe=cfg.probe,
    )


def make_env(cfg: EnvConfig | VelocityEnvConfig | GymEnvConfig, num_envs: int | None = None) -> VecEnv:
    """Build the batched env a config names (``num_envs`` overrides ``cfg.num_envs``)."""
    n = cfg.num_envs if num_envs is None else num_envs
    if cfg.name == "reach1d" and cfg.backend == "gym":
        return GymVecEnv(partial(Reach1D, **reach1d_kwargs(cfg)), n)
    if cfg.name == "velocity" and cfg.backend == "gym":
        return GymVecEnv(partial(make_velocity_env, cfg.task, cfg.velocity_threshold, cfg.max_steps), n)
    if cfg.name == "gym" and cfg.backend == "gym":
        return GymVecEnv(partial(make_cost_env, cfg.id, cfg.step_api, cfg.max_steps, **cfg.kwargs), n)
    raise ValueError(f"env: no implementation for name={cfg.name!r} backend={cfg.backend!r}")


__all__ = [
    "REACH1D_ID", "Reach1D", "GymVecEnv", "Step", "VecEnv", "make_cost_env", "make_env", "make_velocity_env",
    "reach1d_kwargs",
]
