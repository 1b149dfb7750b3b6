"""The training loop every run drives (:class:`TrainingLoop`): collect, check the rollout, update, one
``metrics.csv`` row per member, the observers, the checkpoint. A run has one member; a population has P side by
side in one batch (member i's envs the rows ``[i N, (i + 1) N)``); what differs between them is its
:class:`~cmdp_rl.run.kernel.Kernel`'s.
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
from cmdp_rl.config.saved import CHECKPOINT
from cmdp_rl.deploy.final_policy import FinalPolicy
from cmdp_rl.envs.contract import check_rollout, contract_options
from cmdp_rl.report.metrics import MetricsLogger, spread
from cmdp_rl.report.safety_metrics import cost_rate, normalized_scores
from cmdp_rl.rollout.collector import finished_episodes
from cmdp_rl.run.checkpoint import checkpoint_state, member_entry, save_checkpoint
from cmdp_rl.run.kernel import Kernel
from cmdp_rl.run.progress import Progress

# Who else reads each iteration's rows, as ``observe(iteration, iterations, rows)``: a search's trial
# (tune/trial.py, which may raise optuna.TrialPruned), a population's progress lines.
Observer = Callable[[int, int, list[dict[str, Any]]], None]


def _mean(t: torch.Tensor) -> float:
    return t.mean().item() if t.numel() else float("nan")


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
class TrainingLoop:
    """Iterations of the members ``cfgs`` on ``kernel``, with each member's ``config.yaml`` as written (``saved``,
    for its checkpoint entry), ``logger`` and what it deploys (``finals``); the run directory ``out`` whose
    checkpoint the loop writes, the normalised metrics' ``reference``, the ``observers`` of each iteration's rows;
    ``progress`` shows the first member's rows. ``echo`` prints the loop's own lines (a warning), ``member_echoes``
    each member's (its deployed policy's valuation)."""

    cfgs: Sequence[RunConfig]
    saved: Sequence[dict[str, Any]]
    kernel: Kernel
    loggers: Sequence[MetricsLogger]
    finals: Sequence[FinalPolicy]
    out: Path
    iterations: int
    echo: Callable[[str], None]
    member_echoes: Sequence[Callable[[str], None]]
    reference: Any = None
    observers: Sequence[Observer] = ()
    progress: Progress | None = None

    def __post_init__(self) -> None:
        self.contract = contract_options(self.cfgs[0].env)  # how the rollout's check names the env
        self._entries: dict[int, list[dict[str, Any]]] = {}  # the last checkpoint's members' entries, by iteration
        self._cannot_resume = False

    @property
    def checkpoint_path(self) -> Path:
        return self.out / CHECKPOINT

    @property
    def steps(self) -> int:
        """Each member's env steps so far."""
        return self.kernel.collector.total_steps // len(self.cfgs)

    def run(self, first: int, start: float) -> float:
        """Iterations ``first`` to ``iterations`` (a resume starts past its checkpoint's); ``start`` is the
        ``perf_counter`` at which training time began (earlier by the time a resumed run had). The loggers, the
        env and the progress bar are closed when it ends, however it ends. Returns the training time."""
        try:
            for it in range(first, self.iterations + 1):
                self.iteration(it, start)
        finally:
            if self.progress is not None:
                self.progress.close()
            for logger in self.loggers:
                logger.close()
            self.kernel.env.close()
        return time.perf_counter() - start

    def iteration(self, it: int, start: float) -> None:
        """One iteration: collect, check what was collected, update, log, observe, checkpoint."""
        cfg = self.cfgs[0]
        t0 = time.perf_counter()
        batch = self.kernel.collector.collect()
        steps = self.steps
        # The contract on what was collected (raw values): finite, costs >= 0; vectorised.
        first_step = steps // self.envs_per_member - cfg.rollout_steps + 1
        check_rollout(batch, *self.contract, first_step=first_step)
        try:
            stats = self.update(batch, it)
        except TrainingDiverged as exc:
            path = self.checkpoint_path
            last = f"the last good checkpoint is {path}" if path.exists() else "no checkpoint was written yet"
            raise TrainingDiverged(f"iteration {it}: {exc}; stopped, {last}") from exc
        totals = self.kernel.cost_totals(batch)
        dt = time.perf_counter() - t0
        timing = {"sps": cfg.rollout_steps * self.envs_per_member / dt, "time_s": time.perf_counter() - start}
        self.log(it, batch, steps, stats, totals, timing)
        if it % cfg.checkpoint_every == 0 or it == self.iterations:
            for logger in self.loggers:  # the rows up to this iteration are on disk before the checkpoint names it
                logger.sync()
            self.checkpoint(it, time.perf_counter() - start)

    @property
    def envs_per_member(self) -> int:
        return self.kernel.collector.env.num_envs // len(self.cfgs)

    def update(self, batch: TensorDictBase, it: int) -> list[dict[str, Any]]:
        """Every member's update, then what each deploys reads its actor (when its ``deploy.policy`` keeps one)."""
        stats = self.kernel.update(batch)
        if any(f.wants(it) for f in self.finals):  # the actors as their members' modules hold them
            self.kernel.sync_actors()
            names = self.kernel.env.cost_names
            for f, agent, echo in zip(self.finals, self.kernel.agents, self.member_echoes):
                f.after_update(agent, it, names, echo)
        return stats

    def log(
        self,
        it: int,
        batch: TensorDictBase,
        steps: int,
        stats: list[dict[str, Any]],
        totals: list[list[float]],
        timing: dict[str, float],
    ) -> None:
        """Each member's ``metrics.csv`` row, the progress bar, the observers."""
        n, names = self.envs_per_member, self.kernel.env.cost_names
        parts = [batch] if len(self.cfgs) == 1 else [batch[i * n : (i + 1) * n] for i in range(len(self.cfgs))]
        eps = [finished_episodes(part) for part in parts]
        rows = [
            metrics_row(it, steps, e, s, timing, c.algo.cost_limit, t, names, self.reference)
            for c, e, s, t in zip(self.cfgs, eps, stats, totals)
        ]
        for logger, row, e in zip(self.loggers, rows, eps):
            logger.log(row, force_echo=it == self.iterations, episodes=e)
        if self.progress is not None:
            self.progress.update(rows[0], self.loggers[0].recent)
        for observe in self.observers:
            observe(it, self.iterations, rows)

    def entries(self, it: int) -> list[dict[str, Any]]:
        """The members' checkpoint entries at iteration ``it``: built once (the final one is the last checkpoint's)."""
        if it not in self._entries:
            self.kernel.sync_agents()
            self._entries = {it: [member_entry(*m) for m in zip(self.saved, self.kernel.algos, self.finals)]}
        return self._entries[it]

    def checkpoint(self, it: int, time_s: float) -> None:
        """The checkpoint of iteration ``it``: the members' entries and what they share."""
        try:
            rollout = self.kernel.collector.state_dict()
        except NotImplementedError as exc:  # an env that cannot save itself: evaluable, not resumable
            rollout = None
            if not self._cannot_resume:
                self._cannot_resume = True
                self.echo(f"warning: {exc}; checkpoints of this run can be evaluated but not resumed")
        entries, extras = self.entries(it), self.kernel.checkpoint_extras()
        state = checkpoint_state(self.cfgs[0], it, self.steps, time_s, entries, rollout, self.kernel.rng(), **extras)
        save_checkpoint(self.checkpoint_path, state)
        self.kernel.after_checkpoint(self.checkpoint_path)
