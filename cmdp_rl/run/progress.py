"""Training progress: a live tqdm bar with an ETA on a terminal, plain lines everywhere else.

Live only when the output is ``print`` to a terminal: a log file, CI or a caller's own ``echo`` get
the periodic lines of ``metrics.format_row`` unchanged (a bar's carriage returns would litter them)."""

from __future__ import annotations

import builtins
import sys
from typing import Any, Callable, TextIO

from tqdm import tqdm

from cmdp_rl.report.metrics import RecentEpisodes
from cmdp_rl.report.safety_metrics import per_constraint_values


class Progress:
    """``total_steps`` env steps in all, ``done_steps`` of them before this process (a resume)."""

    def __init__(
        self, total_steps: int, done_steps: int, echo: Callable[[str], None], stream: TextIO | None = None
    ) -> None:
        self.stream = sys.stdout if stream is None else stream
        self.echo = echo
        self.live = echo is builtins.print and self.stream.isatty()
        self._bar = None
        if self.live:
            self._bar = tqdm(
                total=total_steps,
                initial=done_steps,
                unit="step",
                unit_scale=True,
                file=self.stream,
                dynamic_ncols=True,
                smoothing=0.1,
            )

    @property
    def row_echo(self) -> Callable[[str], None]:
        """What the metrics logger prints its periodic lines through: nothing while the bar shows
        the same numbers, the plain echo otherwise."""
        return (lambda line: None) if self.live else self.echo

    def update(self, row: dict[str, Any], recent: RecentEpisodes | None = None) -> None:
        """One iteration's row (``metrics.csv``'s): advance the bar, show its latest numbers (the means of
        ``recent``'s window of finished episodes, once one has ended)."""
        if self._bar is None:
            return
        window = ""
        if recent is not None and len(recent):
            row, window = recent.over(row), f" ({len(recent)} episodes)"
        lam = "/".join(format(v, ".3f") for v in per_constraint_values(row, "lagrange_multiplier"))
        lam = f", lambda {lam}" if lam else ""  # absent for an algorithm that reports no multiplier
        cost = "/".join(format(v, ".2f") for v in per_constraint_values(row, "episode_cost"))
        self._bar.set_postfix_str(f"return {row['episode_return']:.3f}, cost {cost}{lam}{window}", refresh=False)
        self._bar.update(row["step"] - self._bar.n)

    def write(self, line: str) -> None:
        """A message during training, above the bar when there is one."""
        if self._bar is None:
            self.echo(line)
        else:
            self._bar.write(line, file=self.stream)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
