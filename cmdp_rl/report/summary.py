"""The end-of-run summary: how good the trained policy is, in words a newcomer can read.

Generic over tasks; what it knows of a task comes from the env's options class, each piece optional:

- ``optimum(cost_limit) -> float``: the best expected eval return any policy meeting the budget can
  get (an exact solver's answer); the summary prints it and the gap to it. With K > 1 costs it is
  given the list of K budgets (env=fork), with one cost the number;
- ``termination_metric``: the ``eval.json`` key of the fraction of episodes that terminated (a goal
  reached); printed only where the task has one;
- ``termination_note() -> str | None``: why no episode can terminate with these options (printed
  instead of a fraction that is 0 by design).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from cmdp_rl.report.intervals import summary_lines as interval_lines


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


def budgets(cost_limit: float | Sequence[float], k: int) -> list[float]:
    """``algo.cost_limit`` (one number for every constraint, or a list of K) as K budgets."""
    if isinstance(cost_limit, (int, float)):
        return [float(cost_limit)] * k
    if len(cost_limit) != k:
        raise ValueError(f"summary: {len(cost_limit)} budgets for {k} costs")
    return [float(d) for d in cost_limit]


def constraints_of(
    result: Mapping[str, Any], cost_limit: float | Sequence[float], cost_names: Sequence[str] | None = None
) -> list[Constraint]:
    """The run's constraints as ``eval.json`` reports them: with one cost, ``cost`` from
    ``episode_cost``; with ``cost_names`` of K > 1 costs, each by its name from
    ``episode_cost/<name>`` against its own budget."""
    if cost_names is None or len(cost_names) == 1:
        (d,) = budgets(cost_limit, 1)
        return [Constraint("cost", result["episode_cost"], result["episode_cost_std"], d)]
    return [
        Constraint(name, result[f"episode_cost/{name}"], result[f"episode_cost_std/{name}"], d)
        for name, d in zip(cost_names, budgets(cost_limit, len(cost_names)))
    ]


def constraint_view(result: Mapping[str, Any], cost_name: str) -> dict[str, Any]:
    """``result`` with constraint ``cost_name``'s keys (``<key>/<cost_name>``) under their plain
    names: what the one-constraint readers (``intervals.summary_lines``) take."""
    suffix = "/" + cost_name
    return {**result, **{k[: -len(suffix)]: v for k, v in result.items() if k.endswith(suffix)}}


def optimum_of(env_cfg: Any, cost_limit: float | Sequence[float]) -> float | None:
    """The env's constrained optimum at this budget (K budgets for K > 1 costs), where its options
    class offers one."""
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


def interval_summary(
    result: Mapping[str, Any], cost_limit: float | Sequence[float], cost_names: Sequence[str] | None = None
) -> list[str]:
    """The interval estimates' lines (``intervals.summary_lines``) where ``result`` has them (evaluate()
    adds them given a budget): the return's once, then each constraint's cost and violation lines,
    prefixed by its name for K > 1 costs."""
    if "violation_rate_ucb95" in result:
        return interval_lines(result, budgets(cost_limit, 1)[0])
    if cost_names is None or len(cost_names) < 2 or f"violation_rate_ucb95/{cost_names[0]}" not in result:
        return []
    per = [
        interval_lines(constraint_view(result, name), d)
        for name, d in zip(cost_names, budgets(cost_limit, len(cost_names)))
    ]
    lines = [per[0][0]]  # the return's interval: the same for every constraint
    for name, own in zip(cost_names, per):
        lines += [f"{name}: " + line for line in own[1:]]
    return lines


def summary_lines(
    result: Mapping[str, Any],
    env_cfg: Any,
    cost_limit: float | Sequence[float],
    *,
    header: str,
    constraints: Sequence[Constraint] | None = None,
    optimum: float | None = None,
    cost_names: Sequence[str] | None = None,
) -> list[str]:
    """The summary: ``header`` and the episode count, then return (against the optimum where the
    env can compute it: pass ``optimum`` to skip the solver), each constraint against its budget
    with a verdict (``cost_names``: the env's K > 1 costs, each its own line), the interval
    estimates (per constraint), and the termination metric where the task has one."""
    multi = cost_names is not None and len(cost_names) > 1
    if optimum is None:
        k = len(cost_names) if multi else 1
        optimum = optimum_of(env_cfg, budgets(cost_limit, k) if multi else budgets(cost_limit, 1)[0])
    constraints = constraints_of(result, cost_limit, cost_names) if constraints is None else constraints
    lines = [
        f"{header} | eval over {result['episodes']} episodes:",
        "  " + return_line(result["episode_return"], result["episode_return_std"], optimum),
    ]
    lines += ["  " + constraint_line(c) for c in constraints]
    lines += ["  " + line for line in interval_summary(result, cost_limit, cost_names)]
    term = termination_line(result, env_cfg)
    if term is not None:
        lines.append("  " + term)
    return lines
