"""Per-iteration metrics: one CSV row each, and a progress line on the console."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Callable

# Stable column order; every algorithm writes the same names and leaves blank what it lacks.
COLUMNS = [
    "iteration", "step", "episode_return", "episode_cost", "episode_length", "episodes",
    "lagrange_multiplier", "cost_limit", "sps", "time_s",
    "loss_pi", "loss_v", "loss_vc", "entropy", "kl", "clip_fraction",
    # the field's metrics (safety_metrics.py): blank where no reference is given
    "cost_rate", "normalized_return", "normalized_violation", "normalized_cost_rate",
    # CPO (algos/cpo.py): the subproblem's case (0 trpo, 1 constrained, 2 recovery), the accepted
    # fraction of the full step (0: none accepted), the dual's trust-region and cost multipliers,
    # and the accepted step's change of the reward and cost surrogates.
    "cpo_case", "step_fraction", "dual_lambda", "dual_nu", "surr_reward_change", "surr_cost_change",
]


class MetricsLogger:
    def __init__(self, path: str | Path, log_interval: int = 1, echo: Callable[[str], None] = print) -> None:
        self.path = Path(path)
        self.log_interval = log_interval
        self.echo = echo
        self._file = open(self.path, "w", newline="")
        self._writer = csv.DictWriter(self._file, fieldnames=COLUMNS, extrasaction="ignore")
        self._writer.writeheader()
        self._file.flush()

    def log(self, row: dict[str, Any], force_echo: bool = False) -> None:
        self._writer.writerow(row)
        self._file.flush()
        if force_echo or row["iteration"] == 1 or row["iteration"] % self.log_interval == 0:
            self.echo(format_row(row))

    def close(self) -> None:
        self._file.close()


def _fmt(x: float, spec: str) -> str:
    return "   n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def format_row(row: dict[str, Any]) -> str:
    return (
        f"iter {row['iteration']:4d} | step {row['step']:>9,d} | {row['sps']:>8,.0f} steps/s"
        f" | return {_fmt(row['episode_return'], '7.3f')} | cost {_fmt(row['episode_cost'], '6.2f')}"
        f" | lambda {row['lagrange_multiplier']:6.3f}"
    )
