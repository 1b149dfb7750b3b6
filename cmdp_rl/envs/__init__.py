"""Environments. Each env module declares its options and registers itself (``cmdp_rl.config.registry``);
``env=<name>`` selects one. :class:`VecEnv` is the batched interface the collector drives."""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

from cmdp_rl.config.registry import component
from cmdp_rl.config.validation import per_constraint
from cmdp_rl.envs.contract import EnvContractError, check_env
from cmdp_rl.envs.early_termination import EarlyTerminated
from cmdp_rl.envs.gym_cost import make_cost_env
from cmdp_rl.envs.reach1d.batched import TorchReach1D
from cmdp_rl.envs.reach1d.env import Reach1D
from cmdp_rl.envs.vector import GymVecEnv, Step, VecEnv

REACH1D_ID = "cmdp_rl/Reach1D-v0"


def make_env(
    cfg: Any,
    num_envs: int | None = None,
    device: str = "cpu",
    algo: Any = None,
    evaluation: bool = False,
    cut_at: float | Sequence[float] | None = None,
) -> VecEnv:
    """Build the batched env a config names (``num_envs`` overrides ``cfg.num_envs``), its tensors on
    ``device`` (a gymnasium backend steps on the CPU). ``algo``: the algorithm's options, whose
    ``wrap_env(env, evaluation)`` gives the env returned (Sauté's budget state). ``cut_at``: the
    budget(s) of the early-terminated MDP (``envs/early_termination.py``, training envs only), inside
    the algorithm's wrapper, so Sauté's budget state restarts with the cut episode."""
    n = cfg.num_envs if num_envs is None else num_envs
    env = component("env", cfg.name).build(cfg, n, device)
    if cut_at is not None:
        env = EarlyTerminated(env, per_constraint(cut_at, "algo.cost_limit", env.cost_names))
    return env if algo is None else algo.wrap_env(env, evaluation=evaluation)


def make_eval_env(cfg: Any, num_envs: int | None = None, device: str = "cpu", algo: Any = None) -> VecEnv:
    """The env evaluation runs on: ``cfg``'s, with whole episodes only (no staggered start)."""
    if getattr(cfg, "stagger", False):
        cfg = dataclasses.replace(cfg, stagger=False)
    return make_env(cfg, num_envs, device, algo=algo, evaluation=True)


__all__ = [
    "REACH1D_ID",
    "EarlyTerminated",
    "EnvContractError",
    "GymVecEnv",
    "Reach1D",
    "Step",
    "TorchReach1D",
    "VecEnv",
    "check_env",
    "make_cost_env",
    "make_env",
    "make_eval_env",
]
