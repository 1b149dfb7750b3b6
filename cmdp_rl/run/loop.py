"""The training loop every run drives: collect, check the rollout, update, one ``metrics.csv`` row per member,
checkpoint. A run has one member; a population has P side by side in one batch (member i's envs the rows
``[i N, (i + 1) N)``); what differs between them (the update, the checkpoint, the cost counts) is in :class:`Members`.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl.algos import TrainingDiverged
from cmdp_rl.algos.base import per_constraint
from cmdp_rl.config.run_config import RunConfig
from cmdp_rl.envs.contract import check_rollout
from cmdp_rl.report.metrics import MetricsLogger, spread
from cmdp_rl.report.safety_metrics import cost_rate, normalized_scores
from cmdp_rl.rollout.collector import Collector, finished_episodes
from cmdp_rl.run.progress import Progress

# Who else reads each iteration's rows, as ``observe(iteration, iterations, rows)``: a search's trial
# (run/tune_trial.py), which may raise optuna.TrialPruned. A Hydra job gets nothing from its sweeper but its config,
# so the trial registers itself here from a Hydra callback instead of being passed down.
ITERATION_OBSERVERS: list[Callable[[int, int, list[dict[str, Any]]], None]] = []


def _mean(t: torch.Tensor) -> float:
    return t.mean().item() if t.numel() else float("nan")


def contract_options(env_cfg: Any) -> tuple[str, bool]:
    """How contract messages name the env, and whether it allows negative costs (``EnvOptions``)."""
    return env_cfg.env_id(), bool(env_cfg.allow_negative_cost)


def metrics_row(
    iteration: int,
    step: int,
    eps: dict[str, torch.Tensor],
    stats: dict[str, Any],
    timing: dict[str, float],
    cost_limit: Any,
    cost_totals: list[float],
    names: tuple[str, ...],
    reference: Any,
) -> dict[str, Any]:
    """One ``metrics.csv`` row: the episodes ``eps`` that ended in one member's batch (``finished_episodes``), the
    update's ``stats``, the costs collected so far; per-constraint values spread over columns."""
    row = {
        "iteration": iteration,
        "step": step,
        "episode_return": _mean(eps["return"]),
        "episode_cost": [_mean(eps["cost"][:, k]) for k in range(len(names))],
        "episode_length": _mean(eps["length"]),
        "episodes": int(eps["length"].numel()),
        "cost_limit": cost_limit,
        **timing,
        **stats,
        "cost_rate": [cost_rate(total, step) for total in cost_totals],
    }
    limits = per_constraint(cost_limit, "algo.cost_limit", names)
    row.update(normalized_scores(row["episode_return"], row["episode_cost"], row["cost_rate"], limits, reference))
    return spread(row, names)


@dataclasses.dataclass
class Members:
    """What the loop drives: ``cfgs`` and ``loggers``, one per member (P = 1 for a run), the
    ``collector`` of all members' envs, and the member-specific steps:

    - ``update(batch, iteration)``: every member's update on the batch, each member's statistics;
    - ``cost_totals(batch)``: each member's costs collected so far, this batch included;
    - ``checkpoint(iteration, time_s)``: the checkpoint at ``checkpoint_path``;
    - ``report(iteration, rows, seconds)``: anything to say after an iteration's rows (optional)."""

    cfgs: Sequence[RunConfig]
    loggers: Sequence[MetricsLogger]
    collector: Collector
    update: Callable[[TensorDictBase, int], list[dict[str, Any]]]
    cost_totals: Callable[[TensorDictBase], list[list[float]]]
    checkpoint: Callable[[int, float], None]
    checkpoint_path: Path
    reference: Any = None
    report: Callable[[int, list[dict[str, Any]], float], None] | None = None

    @property
    def envs_per_member(self) -> int:
        return self.collector.env.num_envs // len(self.cfgs)

    @property
    def steps(self) -> int:
        """Each member's env steps so far."""
        return self.collector.total_steps // len(self.cfgs)

    def part(self, batch: TensorDictBase, i: int) -> TensorDictBase:
        """Member ``i``'s rows of ``batch``."""
        n = self.envs_per_member
        return batch if len(self.cfgs) == 1 else batch[i * n : (i + 1) * n]


def train_iterations(m: Members, first: int, iterations: int, start: float, progress: Progress | None = None) -> float:
    """Iterations ``first`` to ``iterations`` (a resume starts past its checkpoint's); ``start`` is the ``perf_counter``
    at which training time began (earlier by the time a resumed run had); ``progress`` shows the first member's rows.
    The loggers, the envs and ``progress`` are closed when it ends, however it ends. Returns the training time."""
    try:
        _iterations(m, first, iterations, start, progress)
    finally:
        if progress is not None:
            progress.close()
        for logger in m.loggers:
            logger.close()
        m.collector.env.close()
    return time.perf_counter() - start


def _iterations(m: Members, first: int, iterations: int, start: float, progress: Progress | None) -> None:
    cfg, n = m.cfgs[0], m.envs_per_member
    names = m.collector.env.cost_names
    per_iter = cfg.rollout_steps * n  # steps per member
    env_id, allow_negative_cost = contract_options(cfg.env)
    for it in range(first, iterations + 1):
        t0 = time.perf_counter()
        batch = m.collector.collect()
        steps = m.steps
        # The contract on what was collected (raw values): finite, costs >= 0; vectorised.
        check_rollout(batch, env_id, allow_negative_cost, first_step=steps // n - cfg.rollout_steps + 1)
        try:
            stats = m.update(batch, it)
        except TrainingDiverged as exc:
            path = m.checkpoint_path
            last = f"the last good checkpoint is {path}" if path.exists() else "no checkpoint was written yet"
            raise TrainingDiverged(f"iteration {it}: {exc}; stopped, {last}") from exc
        totals = m.cost_totals(batch)
        dt = time.perf_counter() - t0
        timing = {"sps": per_iter / dt, "time_s": time.perf_counter() - start}
        eps = [finished_episodes(m.part(batch, i)) for i in range(len(m.cfgs))]
        rows = [
            metrics_row(it, steps, e, s, timing, c.algo.cost_limit, t, names, m.reference)
            for c, e, s, t in zip(m.cfgs, eps, stats, totals)
        ]
        for logger, row, e in zip(m.loggers, rows, eps):
            logger.log(row, force_echo=it == iterations, episodes=e)
        if progress is not None:
            progress.update(rows[0], m.loggers[0].recent)
        if m.report is not None:
            m.report(it, rows, dt)
        for observe in ITERATION_OBSERVERS:
            observe(it, iterations, rows)
        if it % cfg.checkpoint_every == 0 or it == iterations:
            for logger in m.loggers:  # the rows up to this iteration are on disk before the checkpoint names it
                logger.sync()
            m.checkpoint(it, time.perf_counter() - start)
