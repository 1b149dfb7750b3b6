"""The training loop: env -> collector -> batch -> advantages -> update -> logger.

``train.py`` is a thin Hydra front for :func:`train`; a user's script can call it directly.
"""

from __future__ import annotations

import dataclasses
import json
import math
import random
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
import yaml

from cmdp_rl.algos import TrainingDiverged, make_algo
from cmdp_rl.checkpoint import save_checkpoint
from cmdp_rl.collector import Collector, finished_episodes
from cmdp_rl.config import RunConfig, validate
from cmdp_rl.envs import make_env
from cmdp_rl.evaluation import evaluate
from cmdp_rl.metrics import MetricsLogger
from cmdp_rl.policies import make_actor_critic

EVAL_SEED_OFFSET = 1_000_003  # evaluation episodes never replay training seeds


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _mean(t: torch.Tensor) -> float:
    return t.mean().item() if t.numel() else float("nan")


def train(cfg: RunConfig, out_dir: str | Path, echo: Callable[[str], None] = print) -> dict[str, Any]:
    """Train as ``cfg`` says, writing ``metrics.csv``, ``checkpoint.pt``, ``config.yaml`` and
    ``eval.json`` under ``out_dir``. Returns the evaluation summary."""
    validate(cfg)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False))
    torch.set_num_threads(cfg.threads)
    seed_everything(cfg.seed)

    env = make_env(cfg.env)
    ac = make_actor_critic(cfg.policy, env)
    algo = make_algo(cfg.algo, ac)
    collector = Collector(env, ac.actor, cfg.rollout_steps, seed=cfg.seed)
    logger = MetricsLogger(out / "metrics.csv", cfg.log_interval, echo)
    per_iter = cfg.rollout_steps * env.num_envs
    iterations = math.ceil(cfg.total_steps / per_iter)
    ckpt_path = out / "checkpoint.pt"

    def checkpoint(iteration: int) -> None:
        save_checkpoint(ckpt_path, {
            "algo": cfg.algo.name, "policy": cfg.policy.name, "config": dataclasses.asdict(cfg),
            "iteration": iteration, "step": collector.total_steps, "algo_state": algo.state_dict(),
        })

    echo(f"training {cfg.algo.name} on {cfg.env.name} ({cfg.env.backend}, {env.num_envs} envs): "
         f"{iterations} iterations of {per_iter} steps, cost limit {cfg.algo.cost_limit}, outputs in {out}")
    start = time.perf_counter()
    try:
        for it in range(1, iterations + 1):
            t0 = time.perf_counter()
            batch = collector.collect()
            try:
                stats = algo.update(batch)
            except TrainingDiverged as exc:
                last = f"the last good checkpoint is {ckpt_path}" if ckpt_path.exists() else "no checkpoint was written yet"
                raise TrainingDiverged(f"iteration {it}: {exc}; stopped, {last}") from exc
            eps = finished_episodes(batch)
            row = {
                "iteration": it, "step": collector.total_steps,
                "episode_return": _mean(eps["return"]), "episode_cost": _mean(eps["cost"]),
                "episode_length": _mean(eps["length"]), "episodes": int(eps["cost"].numel()),
                "cost_limit": cfg.algo.cost_limit, "sps": per_iter / (time.perf_counter() - t0),
                "time_s": time.perf_counter() - start, **stats,
            }
            logger.log(row, force_echo=it == iterations)
            if it % cfg.checkpoint_every == 0 or it == iterations:
                checkpoint(it)
    finally:
        logger.close()
        env.close()
    train_time = time.perf_counter() - start

    eval_env = make_env(cfg.env, num_envs=min(cfg.eval_episodes, cfg.env.num_envs))
    result = evaluate(ac.actor, eval_env, cfg.eval_episodes, cfg.eval_deterministic, seed=cfg.seed + EVAL_SEED_OFFSET)
    eval_env.close()
    result.update({"cost_limit": cfg.algo.cost_limit, "steps": collector.total_steps, "train_time_s": train_time,
                   "torch_threads": torch.get_num_threads()})
    (out / "eval.json").write_text(json.dumps(result, indent=2))
    echo(
        f"done: {cfg.algo.name} {collector.total_steps:,} steps in {train_time:.1f}s | eval over "
        f"{result['episodes']} episodes: return {result['episode_return']:.3f} ± {result['episode_return_std']:.3f}, "
        f"cost {result['episode_cost']:.2f} ± {result['episode_cost_std']:.2f} (limit {cfg.algo.cost_limit}), "
        f"goal reached {result['goal_reached']:.0%}"
    )
    return result
