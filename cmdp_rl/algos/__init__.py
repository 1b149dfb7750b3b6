"""Algorithms, by the name configs use (``algo=<name>``)."""

from __future__ import annotations

from cmdp_rl.algos.lagrange import DualAscent
from cmdp_rl.algos.ppo import PPO, PenaltyPPO, PPOLagrangian, TrainingDiverged
from cmdp_rl.config import PPOConfig
from cmdp_rl.policies import ActorCritic

ALGORITHMS = {"ppo": PPO, "penalty": PenaltyPPO, "ppo_lag": PPOLagrangian}


def make_algo(cfg: PPOConfig, ac: ActorCritic) -> PPO:
    if cfg.name not in ALGORITHMS:
        raise ValueError(f"algo.name: unknown algorithm {cfg.name!r}; allowed: {sorted(ALGORITHMS)}")
    return ALGORITHMS[cfg.name](cfg, ac)


__all__ = ["ALGORITHMS", "DualAscent", "PPO", "PenaltyPPO", "PPOLagrangian", "TrainingDiverged", "make_algo"]
