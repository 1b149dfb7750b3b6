"""The exact constrained optimum of a tabular CMDP, by the occupancy-measure linear program (Altman,
"Constrained Markov Decision Processes", 1999, ch. 3). A stationary policy's discounted occupancy
``rho(s, a) = sum_t gamma^t P(s_t = s, a_t = a)`` makes return and costs linear, ``J = sum rho r``
and ``J_c[k] = sum rho c_k``, and the occupancies of all policies are exactly the non-negative
solutions of the flow equations

    sum_a rho(s', a) - gamma sum_{s, a} P(s' | s, a) rho(s, a) = mu0(s')   for every state s'.

So the CMDP ``max J s.t. J_c[k] <= d_k`` is the LP ``max r.rho`` over that polytope with K more
rows ``c_k.rho <= d_k``, and ``pi(a | s) = rho(s, a) / sum_a rho(s, a)`` is an optimal policy,
randomised in general (at a vertex, in at most K states). We do not scale by ``1 - gamma`` as
Altman does, so the LP's value is ``J`` itself. A finite horizon is the same LP over the states
(t, s), with ``gamma = 1`` and step t's ``P`` leading to step t + 1 (``suite/model.solve``).

The duals: the cost rows' multipliers ``lambda_k = d J* / d d_k >= 0`` and, on the flow rows, the
optimal values of the Lagrangian MDP with reward ``r - lambda . c`` where the LP's policy goes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import sparse
from scipy.optimize import linprog

from cmdp_rl.envs.grid.tabular import TabularCMDP

# A state the optimum visits with probability above VISITED is randomised where its most likely
# action has probability below 1 - MIXED: far above the LP's own tolerances (1e-7 relative).
VISITED = 1e-7
MIXED = 1e-5


@dataclass(frozen=True, eq=False)
class ConstrainedOptimum:
    """``[...]`` is ``[S]`` (discounted) or ``[H, S]`` (a finite horizon)."""

    ret: float  # J(pi*): the optimal return
    costs: np.ndarray  # [K] J_c(pi*)
    policy: np.ndarray  # [..., A] pi*(a | s); uniform in states pi* never visits
    occupancy: np.ndarray  # [..., A] rho*
    multipliers: np.ndarray  # [K] lambda* >= 0, the cost rows' duals (0 for an infinite budget)
    # [...] the flow rows' duals: V* of the MDP with reward r - lambda*.c where pi* goes, >= it elsewhere
    lagrangian_values: np.ndarray
    budgets: np.ndarray  # [K]

    @property
    def randomised_at(self) -> list[tuple[int, ...]]:
        """The states ((t, s) pairs over a finite horizon) where the optimum visits and mixes actions."""
        mixed = (self.occupancy.sum(-1) > VISITED) & (self.policy.max(-1) < 1 - MIXED)
        return [tuple(int(i) for i in at) for at in zip(*np.nonzero(mixed))]

    @property
    def randomised(self) -> bool:
        return bool(self.randomised_at)


class InfeasibleBudgets(ValueError):
    """No policy meets the budgets."""


def policy_of(occupancy: np.ndarray) -> np.ndarray:
    """``pi(a | s) = rho(s, a) / sum_a rho(s, a)`` from an occupancy ``[..., S, A]``; uniform where it is 0."""
    visits = occupancy.sum(-1, keepdims=True)
    return np.where(visits > 0, occupancy / np.where(visits > 0, visits, 1.0), 1.0 / occupancy.shape[-1])


def budgets_of(
    budgets: float | Sequence[float] | None, num_costs: int, default: np.ndarray | None = None
) -> np.ndarray:
    """``budgets`` as K numbers: one number is every constraint's; None, ``default``."""
    d = np.atleast_1d(np.asarray(default if budgets is None else budgets, dtype=float))
    if d.size == 1:
        d = np.full(num_costs, float(d[0]))
    if d.shape != (num_costs,):
        raise ValueError(f"budgets: expected {num_costs} numbers, got {d.tolist()}")
    return d


def occupancy_lp(
    inflow: sparse.spmatrix, r: np.ndarray, c: np.ndarray, mu0: np.ndarray, d: np.ndarray, shape: tuple[int, ...]
) -> ConstrainedOptimum:
    """``max r.rho`` over the flow polytope ``sum_a rho(s', .) - inflow[s', (s, a)] rho(s, a) = mu0(s')``
    with the rows ``c_k.rho <= d_k`` of the finite budgets, by HiGHS' dual simplex (a vertex); ``shape``
    is the occupancy's, states first, actions last. Raises :class:`InfeasibleBudgets` where no policy
    meets the budgets."""
    k = c.shape[0]
    # Each row in its own units: reward and costs may lie 1e4 apart (the suite's), and HiGHS fails to
    # converge on some unscaled instances. The duals are scaled back below.
    r_unit = max(float(np.abs(r).max()), 1e-300)
    c_unit = np.maximum(np.abs(c).max(1), 1e-300)
    rows = np.flatnonzero(np.isfinite(d))
    problem = dict(
        c=-r / r_unit,
        A_ub=sparse.csr_matrix(c[rows] / c_unit[rows, None]) if rows.size else None,
        b_ub=(d / c_unit)[rows] if rows.size else None,
        A_eq=(sparse.kron(sparse.identity(mu0.size), np.ones((1, shape[-1]))) - inflow).tocsr(),
        b_eq=mu0,
        bounds=(0, None),
    )
    res = linprog(**problem, method="highs-ds")
    if res.status == 4:  # numerical trouble: the interior point method, with crossover to a vertex
        res = linprog(**problem, method="highs-ipm")
    if res.status == 2:
        raise InfeasibleBudgets(f"no policy meets the budgets {d.tolist()}")
    if res.status != 0:
        raise RuntimeError(f"occupancy LP failed: {res.message}")
    rho = np.clip(res.x, 0.0, None).reshape(shape)
    multipliers = np.zeros(k)
    if rows.size:  # HiGHS' marginals are d(-J*/r_unit)/d(d_k/c_unit_k) <= 0
        multipliers[rows] = np.clip(-res.ineqlin.marginals, 0.0, None) * r_unit / c_unit[rows]
    return ConstrainedOptimum(
        ret=float(r @ res.x),
        costs=c @ res.x,
        policy=policy_of(rho),
        occupancy=rho,
        multipliers=multipliers,
        lagrangian_values=-res.eqlin.marginals.reshape(shape[:-1]) * r_unit,
        budgets=d,
    )


def solve_constrained(cmdp: TabularCMDP, budgets: float | Sequence[float]) -> ConstrainedOptimum:
    """``max_pi J(pi)`` subject to ``J_c[k](pi) <= budgets[k]`` (one number: every constraint; an
    infinite budget: no constraint), solved exactly by the occupancy LP."""
    s, a, k = cmdp.num_states, cmdp.num_actions, cmdp.num_costs
    inflow = cmdp.gamma * sparse.csr_matrix(cmdp.P.reshape(s * a, s).T)
    return occupancy_lp(inflow, cmdp.r.reshape(-1), cmdp.c.reshape(k, -1), cmdp.mu0, budgets_of(budgets, k), (s, a))
