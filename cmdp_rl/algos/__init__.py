"""Algorithms, by the name configs use (``algo=<name>``)."""

from __future__ import annotations

from cmdp_rl.algos.base import Algorithm, TrainingDiverged
from cmdp_rl.algos.cpo import CPO
from cmdp_rl.algos.lagrange import DualAscent, MultiplierController, PIDLagrangian
from cmdp_rl.algos.ppo import PPO, PenaltyPPO, PIDLagrangianPPO, PPOLagrangian
from cmdp_rl.config import AlgoConfig
from cmdp_rl.policies import ActorCritic

ALGORITHMS: dict[str, type] = {
    "ppo": PPO, "penalty": PenaltyPPO, "ppo_lag": PPOLagrangian, "pid_lag": PIDLagrangianPPO, "cpo": CPO,
}


def make_algo(cfg: AlgoConfig, ac: ActorCritic) -> Algorithm:
    if cfg.name not in ALGORITHMS:
        raise ValueError(f"algo.name: unknown algorithm {cfg.name!r}; allowed: {sorted(ALGORITHMS)}")
    return ALGORITHMS[cfg.name](cfg, ac)


__all__ = [
    "ALGORITHMS", "Algorithm", "CPO", "DualAscent", "MultiplierController", "PIDLagrangian", "PIDLagrangianPPO",
    "PPO", "PenaltyPPO", "PPOLagrangian", "TrainingDiverged", "make_algo",
]
