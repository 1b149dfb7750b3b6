"""The end-of-run summary: how good the trained policy is, in words a newcomer can read.

Generic over tasks; what it knows of a task comes from the env's options class, each piece optional:

- ``optimum(cost_limit) -> float``: the best expected eval return any policy meeting the budget can
  get (an exact solver's answer); the summary prints it and the gap to it;
- ``termination_metric``: the ``eval.json`` key of the fraction of episodes that terminated (a goal
  reached); printed only where the task has one;
- ``termination_note() -> str | None``: why no episode can terminate with these options (printed
  instead of a fraction that is 0 by design).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from cmdp_rl.intervals import summary_lines as interval_lines


@dataclass(frozen=True)
class Constraint:
    """One constraint's evaluation: mean and std of its episode cost, and its budget d."""

    name: str
    mean: float
    std: float
    budget: float

    @property
    def within(self) -> bool:
        return self.mean <= self.budget


def constraints_of(result: Mapping[str, Any], cost_limit: float) -> list[Constraint]:
    """The run's constraints as ``eval.json`` reports them (this toolkit has one cost signal)."""
    return [Constraint("cost", result["episode_cost"], result["episode_cost_std"], cost_limit)]


def optimum_of(env_cfg: Any, cost_limit: float) -> float | None:
    """The env's constrained optimum at this budget, where its options class offers one."""
    solver = getattr(env_cfg, "optimum", None)
    return None if solver is None else float(solver(cost_limit))


def return_line(mean: float, std: float, optimum: float | None) -> str:
    line = f"return {mean:.3f} ± {std:.3f}"
    if optimum is None:
        return line
    gap = optimum - mean
    share = f" ({gap / abs(optimum):.1%} of it)" if optimum != 0 else ""
    return f"{line} | constrained optimum {optimum:.3f} (exact solver) | gap {gap:.3f}{share}"


def constraint_line(c: Constraint) -> str:
    verdict = "within budget" if c.within else f"over budget by {c.mean - c.budget:.2f}"
    return f"{c.name} {c.mean:.2f} ± {c.std:.2f} against budget {c.budget:g}: {verdict}"


def termination_line(result: Mapping[str, Any], env_cfg: Any) -> str | None:
    note = getattr(env_cfg, "termination_note", None)
    note = None if note is None else note()
    if note is not None:
        return note
    metric = getattr(env_cfg, "termination_metric", None)
    if metric is None or metric not in result:
        return None
    return f"{metric.replace('_', ' ')} in {result[metric]:.0%} of episodes"


def summary_lines(
    result: Mapping[str, Any], env_cfg: Any, cost_limit: float, *, header: str,
    constraints: Sequence[Constraint] | None = None, optimum: float | None = None,
) -> list[str]:
    """The summary: ``header`` and the episode count, then return (against the optimum where the
    env can compute it: pass ``optimum`` to skip the solver), each constraint against its budget
    with a verdict, and the termination metric where the task has one."""
    if optimum is None:
        optimum = optimum_of(env_cfg, cost_limit)
    constraints = constraints_of(result, cost_limit) if constraints is None else constraints
    lines = [f"{header} | eval over {result['episodes']} episodes:",
             "  " + return_line(result["episode_return"], result["episode_return_std"], optimum)]
    lines += ["  " + constraint_line(c) for c in constraints]
    if "violation_rate_ucb95" in result:  # the interval estimates evaluate() adds given a budget
        lines += ["  " + line for line in interval_lines(result, cost_limit)]
    term = termination_line(result, env_cfg)
    if term is not None:
        lines.append("  " + term)
    return lines
