"""The end-of-run summary, in words a newcomer can read. From the env's options, each optional: ``optimum(cost_limit)``
(an exact solver's best return within the budget; K budgets for K > 1 costs), ``termination_metric`` (the
``eval.json`` key of the share of terminated episodes), ``termination_note()`` (why none can terminate)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from cmdp_rl.config.validation import per_constraint
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


def constraints_of(
    cost_limit: float | Sequence[float], cost_names: Sequence[str] | None
) -> list[tuple[str, str, float]]:
    """(name, eval.json key suffix, budget) per constraint: (``cost``, ``""``) for one cost, else ``/<name>``."""
    if cost_names is None or len(cost_names) == 1:
        return [("cost", "", *per_constraint(cost_limit, "algo.cost_limit", ["cost"]))]
    return [(n, "/" + n, d) for n, d in zip(cost_names, per_constraint(cost_limit, "algo.cost_limit", cost_names))]


def optimum_of(env_cfg: Any, cost_limit: float | Sequence[float]) -> float | None:
    """The env's constrained optimum at this budget (K budgets for K > 1 costs), where its options offer one."""
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
    note = getattr(env_cfg, "termination_note", lambda: None)()
    if note is not None:
        return note
    metric = getattr(env_cfg, "termination_metric", None)
    if metric is None or metric not in result:
        return None
    return f"{metric.replace('_', ' ')} in {result[metric]:.0%} of episodes"


def interval_summary(
    result: Mapping[str, Any], cost_limit: float | Sequence[float], cost_names: Sequence[str] | None = None
) -> list[str]:
    """The interval estimates' lines (``intervals.summary_lines``) where ``result`` has them: the return's
    once, then each constraint's cost and violation lines, prefixed by its name for K > 1 costs."""
    named = constraints_of(cost_limit, cost_names)
    if f"violation_rate_ucb95{named[0][1]}" not in result:
        return []
    if len(named) == 1:
        return interval_lines(result, named[0][2])
    # Each constraint's keys under their plain names, as the one-constraint lines read them.
    per = [
        interval_lines({**result, **{k[: -len(s)]: v for k, v in result.items() if k.endswith(s)}}, d)
        for _, s, d in named
    ]
    return [per[0][0], *(f"{name}: {line}" for (name, _, _), own in zip(named, per) for line in own[1:])]


def summary_lines(
    result: Mapping[str, Any],
    env_cfg: Any,
    cost_limit: float | Sequence[float],
    *,
    header: str,
    optimum: float | None = None,
    cost_names: Sequence[str] | None = None,
) -> list[str]:
    """The summary: ``header`` and episode count, return (against the env's optimum, or ``optimum``), each
    constraint against its budget, the intervals and the termination metric where the task has one."""
    named = constraints_of(cost_limit, cost_names)
    if optimum is None:
        optimum = optimum_of(env_cfg, named[0][2] if len(named) == 1 else [d for _, _, d in named])
    constraints = [Constraint(n, result[f"episode_cost{s}"], result[f"episode_cost_std{s}"], d) for n, s, d in named]
    lines = [
        f"{header} | eval over {result['episodes']} episodes:",
        "  " + return_line(result["episode_return"], result["episode_return_std"], optimum),
        *("  " + constraint_line(c) for c in constraints),
        *("  " + line for line in interval_summary(result, cost_limit, cost_names)),
    ]
    term = termination_line(result, env_cfg)
    lines = lines if term is None else [*lines, "  " + term]
    return [*lines, *("  " + line for line in other_lines(result, named))]


def _interval(pair: Sequence[float] | None, fmt: str) -> str:
    return "" if pair is None else f" [{pair[0]:{fmt}}, {pair[1]:{fmt}}]"


def other_lines(result: Mapping[str, Any], named: Sequence[tuple[str, str, float]]) -> list[str]:
    """The other evaluation mode's line (sampled actions beside the mean action's, or the reverse) and the
    training episodes' line, where ``result`` has them (``modes``, ``training_episodes``)."""
    lines = []
    modes = result.get("modes") or {}
    for r in modes.values():
        if r.get("deterministic") == result.get("deterministic"):
            continue
        costs = [
            f"{n} {r[f'episode_cost{s}']:.2f}{_interval(r.get(f'episode_cost_ci95{s}'), '.2f')}" for n, s, _ in named
        ]
        what = "mean action" if r.get("deterministic") else "sampled actions"
        ret = f"return {r['episode_return']:.3f}{_interval(r.get('episode_return_ci95'), '.3f')}"
        lines.append(f"{what} ({r['episodes']} episodes): {ret} | " + " | ".join(costs))
    train = result.get("training_episodes")
    if train:
        costs = [f"{n} {train[f'episode_cost{s}']:.2f}" for n, s, _ in named]
        lines.append(
            f"training episodes (the last {train['episodes']}, sampled actions): return {train['episode_return']:.3f} | "
            + " | ".join(costs)
        )
    return lines
