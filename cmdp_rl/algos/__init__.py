"""Algorithms: each module declares its options and registers itself; ``algo=<name>`` selects one."""

from __future__ import annotations

from cmdp_rl.algos.base import AlgoConfig, Algorithm, TrainingDiverged
from cmdp_rl.config.registry import component


def make_algo(cfg: AlgoConfig, agent) -> Algorithm:
    """The algorithm ``cfg.name`` names, training the networks of ``agent``."""
    return component("algo", cfg.name).build(cfg, agent)


__all__ = ["AlgoConfig", "Algorithm", "TrainingDiverged", "make_algo"]
