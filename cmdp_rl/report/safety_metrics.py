"""The safe-RL field's run metrics (Ray, Achiam, Amodei 2019, sec. 5; Safety Gym's ``bench/bench_utils.py``):
the cost rate ``rho_c`` (all costs incurred in training over the env steps so far), and, against an
unconstrained PPO reference trained on the same env for as many steps,
    normalized return          J_r / J_r^PPO
    normalized violation       max(0, J_c - d) / max(eps, J_c^PPO - d),   eps = 1e-6
    normalized cost rate       rho_c / rho_c^PPO
(``J_r``, ``J_c`` the final policy's mean return and cost, ``d`` the budget; blank without a reference). With
K costs they are per constraint, against a reference run's per-cost numbers. The reference itself (``reference:``, a
run's directory or its numbers): ``config/reference.py``."""

from __future__ import annotations

import math
from typing import Any

from cmdp_rl.config.reference import Reference

EPSILON = 1e-6  # Safety Gym's: keeps the violation finite when PPO itself is within the budget
NORMALIZED = ("normalized_return", "normalized_violation", "normalized_cost_rate")


def cost_rate(total_cost: float, total_steps: int) -> float:
    return total_cost / total_steps if total_steps else math.nan


def _listed(x: Any, k: int) -> list:
    return list(x) if isinstance(x, (list, tuple)) else [x] * k


def _reference_values(x: Any, k: int) -> list:
    """A reference's per-constraint numbers: a list of K as it is; a single number only for K = 1."""
    ok = len(x) == k if isinstance(x, (list, tuple)) else k == 1
    return _listed(x, 1) if ok else [None] * k


def normalized_scores(
    episode_return: float,
    episode_cost: float | list[float],
    rate: float | list[float],
    cost_limit: float | list[float],
    ref: Reference | None,
) -> dict[str, Any]:
    """The normalized metrics (lists of K for K costs); None where the reference lacks a number or divides by 0."""
    single = not isinstance(episode_cost, (list, tuple))
    if ref is None:
        return dict.fromkeys(NORMALIZED)
    costs = _listed(episode_cost, 1)
    k = len(costs)
    rates, limits = _listed(rate, k), _listed(cost_limit, k)
    ref_costs, ref_rates = _reference_values(ref.episode_cost, k), _reference_values(ref.cost_rate, k)
    violation = [
        None if rc is None else max(0.0, c - d) / max(EPSILON, rc - d) for c, d, rc in zip(costs, limits, ref_costs)
    ]
    cost_rates = [r / rr if rr else None for r, rr in zip(rates, ref_rates)]
    return {
        "normalized_return": episode_return / ref.episode_return if ref.episode_return else None,
        "normalized_violation": violation[0] if single else violation,
        "normalized_cost_rate": cost_rates[0] if single else cost_rates,
    }


def per_constraint_values(row: dict[str, Any], name: str) -> list:
    """``name``'s values in a metrics row or eval.json: its one entry, or its ``name/<cost>`` entries in order."""
    return [row[name]] if name in row else [v for k, v in row.items() if k.startswith(name + "/")]
