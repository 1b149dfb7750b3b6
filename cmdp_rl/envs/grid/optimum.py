"""The exact constrained optimum of a tabular CMDP, by the occupancy-measure linear program.

Altman, "Constrained Markov Decision Processes" (1999), ch. 3: for the discounted criterion a
stationary policy's discounted state-action occupancy ``rho(s, a) = sum_t gamma^t P(s_t = s, a_t = a)``
turns return and costs into linear functions, ``J = sum rho r`` and ``J_c[k] = sum rho c_k``, and
the occupancies of all policies are exactly the non-negative solutions of the flow equations

    sum_a rho(s', a) - gamma sum_{s, a} P(s' | s, a) rho(s, a) = mu0(s')   for every state s'.

So the CMDP ``max J s.t. J_c[k] <= d_k`` is the LP ``max r.rho`` over that polytope with K more
rows ``c_k.rho <= d_k``, and ``pi(a | s) = rho(s, a) / sum_a rho(s, a)`` is an optimal policy,
randomised in general (at a vertex, in at most K states). We do not scale by ``1 - gamma`` as
Altman does, so the LP's value is ``J`` itself.

The LP's dual variables are the rest of the answer: the multipliers ``lambda_k >= 0`` of the cost
rows (``d J* / d d_k``, zero where a constraint does not bind) and, on the flow rows, the optimal
values of the Lagrangian MDP with reward ``r - lambda . c``, for which the LP's policy is optimal
(in the states that policy visits; elsewhere the dual only bounds them from above).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cmdp_rl.envs.grid.tabular import TabularCMDP


@dataclass(frozen=True, eq=False)
class ConstrainedOptimum:
    ret: float  # J(pi*): the optimal return
    costs: np.ndarray  # [K] J_c(pi*)
    policy: np.ndarray  # [S, A] pi*(a | s); uniform in states pi* never visits
    occupancy: np.ndarray  # [S, A] rho*
    multipliers: np.ndarray  # [K] lambda* >= 0, the cost rows' duals (0 for an infinite budget)
    # [S] the flow rows' duals: V* of the MDP with reward r - lambda*.c where pi* goes, >= it elsewhere
    lagrangian_values: np.ndarray
    budgets: np.ndarray  # [K]


class InfeasibleBudgets(ValueError):
    """No policy meets the budgets."""


def policy_of(occupancy: np.ndarray) -> np.ndarray:
    """``pi(a | s) = rho(s, a) / sum_a rho(s, a)`` from an occupancy ``[..., S, A]``; uniform where it is 0."""
    visits = occupancy.sum(-1, keepdims=True)
    return np.where(visits > 0, occupancy / np.where(visits > 0, visits, 1.0), 1.0 / occupancy.shape[-1])


def solve_constrained(cmdp: TabularCMDP, budgets: float | Sequence[float]) -> ConstrainedOptimum:
    """``max_pi J(pi)`` subject to ``J_c[k](pi) <= budgets[k]`` (one number: every constraint; an
    infinite budget: no constraint), solved exactly by the occupancy LP with HiGHS' dual simplex
    (a vertex solution). Raises :class:`InfeasibleBudgets` if no policy meets the budgets."""
    from scipy.optimize import linprog  # scipy is only needed here

    num_s, num_a, num_k = cmdp.num_states, cmdp.num_actions, cmdp.num_costs
    d = np.broadcast_to(np.asarray(budgets, dtype=np.float64), (num_k,)).copy()
    # Flow rows: A_eq[s', (s, a)] = 1[s == s'] - gamma P(s' | s, a)
    a_eq = np.repeat(np.eye(num_s), num_a, axis=1) - cmdp.gamma * cmdp.P.reshape(num_s * num_a, num_s).T
    rows = np.flatnonzero(np.isfinite(d))
    res = linprog(
        c=-cmdp.r.reshape(-1),
        A_ub=cmdp.c.reshape(num_k, -1)[rows] if rows.size else None,
        b_ub=d[rows] if rows.size else None,
        A_eq=a_eq,
        b_eq=cmdp.mu0,
        bounds=(0, None),
        method="highs-ds",
    )
    if res.status == 2:
        raise InfeasibleBudgets(f"no policy meets the budgets {d.tolist()}")
    if res.status != 0:
        raise RuntimeError(f"occupancy LP failed: {res.message}")
    rho = np.clip(res.x, 0.0, None).reshape(num_s, num_a)
    multipliers = np.zeros(num_k)
    if rows.size:
        # HiGHS reports d(objective)/d(b_ub) for the minimised -r.rho: <= 0, the negated multiplier.
        multipliers[rows] = np.clip(-res.ineqlin.marginals, 0.0, None)
    return ConstrainedOptimum(
        ret=float(cmdp.r.reshape(-1) @ res.x),
        costs=cmdp.c.reshape(num_k, -1) @ res.x,
        policy=policy_of(rho),
        occupancy=rho,
        multipliers=multipliers,
        lagrangian_values=-res.eqlin.marginals,
        budgets=d,
    )


__all__ = ["ConstrainedOptimum", "InfeasibleBudgets", "policy_of", "solve_constrained"]
