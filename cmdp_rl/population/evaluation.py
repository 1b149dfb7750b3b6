"""The final evaluation of every agent at once, each agent's result as ``evaluate`` gives it.

Each agent runs its single run's evaluation: ``min(eval_episodes, num_envs)`` envs of its own
options without staggered starts, seeded with its evaluation seed (``seed + EVAL_SEED_OFFSET``, for
the envs and for its action samples), each env contributing its quota of first episodes. The
summary of an agent's episodes is ``evaluation.py``'s (``_spread``, ``_intervals``).
"""

from __future__ import annotations

from typing import Any, Sequence

import torch

from cmdp_rl.collector import Collector
from cmdp_rl.config import RunConfig
from cmdp_rl.evaluation import EVAL_SEED_OFFSET, episode_rows, summarize_episodes
from cmdp_rl.population.agent import PopulationAgent
from cmdp_rl.population.env import population_env

CHUNK = 128  # steps per collect, as evaluation.py


def evaluate_population(
    agent: PopulationAgent, cfgs: Sequence[RunConfig], device: torch.device
) -> list[dict[str, Any]]:
    cfg = cfgs[0]
    n = min(cfg.eval_episodes, cfg.env.num_envs)
    seeds = [c.seed + EVAL_SEED_OFFSET for c in cfgs]
    env = population_env(cfgs, n, seeds, device, evaluation=True)
    training = agent.generators
    agent.generators = [torch.Generator(device=device).manual_seed(s) for s in seeds]
    try:
        collector = Collector(env, agent, CHUNK, seed=None, deterministic=cfg.eval_deterministic)
        quota = [cfg.eval_episodes // n + (1 if j < cfg.eval_episodes % n else 0) for j in range(n)]
        rows = episode_rows(collector, quota * len(cfgs))
    finally:
        agent.generators = training
    metric = cfg.env.termination_metric
    return [
        summarize_episodes(
            [row for r in rows[i * n : (i + 1) * n] for row in r],
            env.cost_names,
            c.eval_deterministic,
            metric,
            c.algo.cost_limit,
        )
        for i, c in enumerate(cfgs)
    ]


__all__ = ["evaluate_population"]
