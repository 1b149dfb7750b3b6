"""Environments: the seed's Reach1D and the batched interface the collector drives."""

from __future__ import annotations

from functools import partial

from cmdp_rl.config import EnvConfig
from cmdp_rl.envs.reach1d import Reach1D
from cmdp_rl.envs.reach1d_torch import NoiseSource, TorchNoise, TorchReach1D
from cmdp_rl.envs.vector import GymVecEnv, Step, VecEnv

REACH1D_ID = "cmdp_rl/Reach1D-v0"


def reach1d_kwargs(cfg: EnvConfig) -> dict:
    """The Reach1D constructor arguments an :class:`EnvConfig` asks for."""
    return dict(
        obs_noise=cfg.obs_noise, wall_x=cfg.wall_x, max_steps=cfg.max_steps, goal=cfg.goal,
        wall=cfg.wall, start=cfg.start, probe=cfg.probe,
    )


def make_env(cfg: EnvConfig, num_envs: int | None = None, device: str = "cpu") -> VecEnv:
    """Build the batched env a config names (``num_envs`` overrides ``cfg.num_envs``).

    ``device`` is where the env's tensors live: the torch backend steps there; the gym backend
    steps on the CPU and moves its tensors there.
    """
    n = cfg.num_envs if num_envs is None else num_envs
    if cfg.name == "reach1d" and cfg.backend == "gym":
        return GymVecEnv(partial(Reach1D, **reach1d_kwargs(cfg)), n, device=device)
    if cfg.name == "reach1d" and cfg.backend == "torch":
        return TorchReach1D(n, **reach1d_kwargs(cfg), stagger=cfg.stagger, device=device)
    raise ValueError(f"env: no implementation for name={cfg.name!r} backend={cfg.backend!r}")


__all__ = [
    "REACH1D_ID", "GymVecEnv", "NoiseSource", "Reach1D", "Step", "TorchNoise", "TorchReach1D", "VecEnv",
    "make_env", "reach1d_kwargs",
]
