"""The end of a run: the deployed policy put into its agent, its evaluation in both modes, ``eval.json`` and the
summary it prints (:func:`finish_run`); :func:`write_result` and :func:`evaluate_run` are a population's members'
too."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, Callable

import torch

from cmdp_rl.algos.base import per_constraint
from cmdp_rl.config.run_config import RunConfig
from cmdp_rl.config.saved import EVAL, METRICS
from cmdp_rl.deploy.average import ParameterAverage, deployed
from cmdp_rl.deploy.final_policy import FinalPolicy
from cmdp_rl.deploy.mixture import IterateSnapshots
from cmdp_rl.envs import make_eval_env
from cmdp_rl.report.metrics import MetricsLogger, constraint_name, read_metrics, spread, training_episodes
from cmdp_rl.report.safety_metrics import cost_rate, normalized_scores
from cmdp_rl.report.summary import summary_lines
from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET, both_modes, evaluate
from cmdp_rl.run.kernel import Kernel


def complete_result(
    result: dict[str, Any],
    cfg: RunConfig,
    steps: int,
    train_time: float,
    cost_totals: list[float],
    names: tuple[str, ...],
    reference: Any,
    average: ParameterAverage | IterateSnapshots | None = None,
) -> None:
    """Add to an evaluation's ``result`` what ``eval.json`` records of the run: budget, steps, train
    time, threads, the deployed policy (``final_policy``, the run's ``deploy.policy``, and how many iterations
    ``average`` holds), cost rates and normalised scores per constraint, the reference."""
    result.update(
        {
            "cost_limit": cfg.algo.cost_limit,
            "steps": steps,
            "train_time_s": train_time,
            "torch_threads": torch.get_num_threads(),
            "final_policy": cfg.deploy.policy,
            "averaged_iterations": None if average is None else average.count,
        }
    )
    if isinstance(average, IterateSnapshots):  # the mixture's snapshots, and their weights if chosen
        result.update(average.result_keys(cfg.deploy.weights))
    k = len(names)
    limits = per_constraint(cfg.algo.cost_limit, "algo.cost_limit", names)
    eval_costs = [result[constraint_name("episode_cost", c, k)] for c in names]
    rates = [cost_rate(total, steps) for total in cost_totals]
    per_cost = {"cost_rate": rates, **normalized_scores(result["episode_return"], eval_costs, rates, limits, reference)}
    if k > 1:  # one budget per constraint, as cost_limit/<cost>
        del result["cost_limit"]
        per_cost = {"cost_limit": limits, **per_cost}
    result.update(spread(per_cost, names))
    result["reference"] = None if reference is None else dataclasses.asdict(reference)


def write_result(out: Path, result: dict[str, Any], cfg: RunConfig, *args: Any) -> None:
    """:func:`complete_result` (``args`` are its after ``cfg``), then the run's ``eval.json``."""
    complete_result(result, cfg, *args)
    result["training_episodes"] = training_episodes(read_metrics(out / METRICS))
    (out / EVAL).write_text(json.dumps(result, indent=2))


def evaluate_run(cfg: RunConfig, agent: Any) -> dict[str, Any]:
    """A run's final evaluation of ``agent`` in both modes (:func:`~cmdp_rl.run.evaluation.both_modes`):
    ``eval_episodes`` episodes on min(eval_episodes, num_envs) envs of its own, seeded with the run's
    evaluation seed, for the mean action and for sampled actions."""

    def one_mode(deterministic: bool) -> dict[str, Any]:
        eval_env = make_eval_env(
            cfg.env, num_envs=min(cfg.eval_episodes, cfg.env.num_envs), device=cfg.device, algo=cfg.algo
        )
        try:
            return evaluate(
                agent,
                eval_env,
                cfg.eval_episodes,
                deterministic,
                seed=cfg.seed + EVAL_SEED_OFFSET,
                termination_metric=cfg.env.termination_metric,  # what the env says termination means
                cost_limit=cfg.algo.cost_limit,
            )
        finally:
            eval_env.close()

    return both_modes(one_mode, cfg.eval_deterministic)


def finish_run(
    cfg: RunConfig,
    out: Path,
    kernel: Kernel,
    final: FinalPolicy,
    logger: MetricsLogger,
    train_time: float,
    reference: Any,
    echo: Callable[[str], None],
) -> dict[str, Any]:
    """A run after its last iteration: its deployed policy into its agent, evaluated (:func:`evaluate_run`), its
    ``eval.json`` written (:func:`write_result`) and the summary printed; returns the evaluation."""
    agent, names = kernel.agents[0], kernel.env.cost_names
    final.deploy(agent)
    result = evaluate_run(cfg, agent)
    steps = kernel.collector.total_steps
    write_result(out, result, cfg, steps, train_time, kernel.cost_totals()[0], names, reference, final.kept)
    logger.finish(result)  # the summary beside the metrics (logger=wandb)
    header = f"done: {cfg.algo.name} {steps:,} steps in {train_time:.1f}s; {deployed(result)}"
    for line in summary_lines(result, cfg.env, cfg.algo.cost_limit, header=header, cost_names=names):
        echo(line)
    return result
