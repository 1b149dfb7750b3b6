"""The exact constrained optimum of a finite-horizon CMDP (``model.py``) by the occupancy-measure LP.

Altman, "Constrained Markov Decision Processes" (1999), ch. 3 (and Puterman 1994, sec. 6.9, for
the unconstrained LP): a policy's occupancy ``x_t(s, a) = P(s_t = s, a_t = a)`` makes return and
costs linear, ``J = sum_t r . x_t`` and ``J_c[k] = sum_t c_k . x_t``, and the occupancies of all
(Markov, randomised) policies are exactly the non-negative solutions of the flow equations

    sum_a x_0(s, a)     = mu0(s)
    sum_a x_{t+1}(s, a) = sum_{s', a'} P(s | s', a') x_t(s', a')      for t < H - 1.

So ``max J s.t. J_c[k] <= d_k`` is the LP ``max r . x`` over that polytope with K more rows, and
``pi_t(a | s) = x_t(s, a) / sum_a x_t(s, a)`` is an optimal policy. The dual simplex returns a
vertex, which randomises in at most K (t, s) pairs; where it randomises in none, a deterministic
policy is optimal. Undiscounted: the finite horizon makes the sums finite, and they are what a
run's evaluation measures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import sparse
from scipy.optimize import linprog

from cmdp_rl.envs.grid.optimum import InfeasibleBudgets, policy_of
from cmdp_rl.envs.suite.model import FiniteCMDP

# A (t, s) the optimum visits with probability above VISITED is randomised where its most likely
# action has probability below 1 - MIXED: far above the LP's own tolerances (1e-7 relative).
VISITED = 1e-7
MIXED = 1e-5


@dataclass(frozen=True, eq=False)
class FiniteOptimum:
    ret: float  # J*
    costs: np.ndarray  # [K] J_c(pi*)
    policy: np.ndarray  # [H, S, A] pi*_t(a | s); uniform where pi* never goes
    occupancy: np.ndarray  # [H, S, A] x*
    multipliers: np.ndarray  # [K] lambda* >= 0 (dJ*/dd_k; 0 where a constraint does not bind)
    budgets: np.ndarray  # [K]

    @property
    def randomised_at(self) -> list[tuple[int, int]]:
        """The (t, s) pairs where the optimum visits and mixes actions."""
        visits = self.occupancy.sum(-1)
        mixed = (visits > VISITED) & (self.policy.max(-1) < 1 - MIXED)
        return [(int(t), int(s)) for t, s in zip(*np.nonzero(mixed))]

    @property
    def randomised(self) -> bool:
        return bool(self.randomised_at)


def budgets_of(cmdp: FiniteCMDP, budgets: float | Sequence[float] | None) -> np.ndarray:
    """``budgets`` as K numbers: None, the instance's own; one number, every constraint's."""
    if budgets is None:
        return np.asarray(cmdp.budgets, dtype=float)
    d = np.atleast_1d(np.asarray(budgets, dtype=float))
    if d.size == 1:
        d = np.full(cmdp.num_costs, float(d[0]))
    if d.shape != (cmdp.num_costs,):
        raise ValueError(f"budgets: expected {cmdp.num_costs} numbers, got {d.tolist()}")
    return d


def solve(cmdp: FiniteCMDP, budgets: float | Sequence[float] | None = None) -> FiniteOptimum:
    """``max_pi J(pi)`` s.t. ``J_c[k](pi) <= budgets[k]`` (None: the instance's budgets; an infinite
    budget: no constraint) by the occupancy LP with HiGHS' dual simplex. Raises
    :class:`InfeasibleBudgets` where no policy meets the budgets."""
    H, S, A, K = cmdp.horizon, cmdp.num_states, cmdp.num_actions, cmdp.num_costs
    d = budgets_of(cmdp, budgets)
    # Each row in its own units: reward and costs span 1e-2..1e2 apart, and HiGHS fails to converge
    # on some unscaled instances. The multipliers are scaled back below.
    r_unit = max(float(np.abs(cmdp.r).max()), 1e-300)
    c_unit = np.maximum(np.abs(cmdp.c).reshape(K, -1).max(1), 1e-300)
    # Variables x_t(s, a) in (t, s, a) order. Flow rows (t, s): sum_a x_t(s, .) minus, for t >= 1,
    # what step t - 1 sends into s.
    total = sparse.kron(sparse.identity(S), np.ones((1, A)))  # [S, S A]
    inflow = sparse.csr_matrix(cmdp.P.reshape(S * A, S).T)  # [S, S A]
    a_eq = sparse.kron(sparse.identity(H), total) - sparse.kron(sparse.eye(H, k=-1), inflow)
    b_eq = np.concatenate([cmdp.mu0, np.zeros((H - 1) * S)])
    rows = np.flatnonzero(np.isfinite(d))
    unit_c = cmdp.c.reshape(K, S * A) / c_unit[:, None]
    problem = dict(
        c=-np.tile(cmdp.r.reshape(-1), H) / r_unit,
        A_ub=sparse.csr_matrix(np.tile(unit_c, (1, H))[rows]) if rows.size else None,
        b_ub=(d / c_unit)[rows] if rows.size else None,
        A_eq=a_eq.tocsr(),
        b_eq=b_eq,
        bounds=(0, None),
    )
    res = linprog(**problem, method="highs-ds")
    if res.status == 4:  # numerical trouble: the interior point method, with crossover to a vertex
        res = linprog(**problem, method="highs-ipm")
    if res.status == 2:
        raise InfeasibleBudgets(f"no policy meets the budgets {d.tolist()}")
    if res.status != 0:
        raise RuntimeError(f"finite-horizon occupancy LP failed: {res.message}")
    x = np.clip(res.x, 0.0, None).reshape(H, S, A)
    multipliers = np.zeros(K)
    if rows.size:  # HiGHS' marginals are d(-J*/r_unit)/d(d_k/c_unit_k) <= 0
        multipliers[rows] = np.clip(-res.ineqlin.marginals, 0.0, None) * r_unit / c_unit[rows]
    return FiniteOptimum(
        ret=float(np.tile(cmdp.r.reshape(-1), H) @ res.x),
        costs=cmdp.c.reshape(K, -1) @ x.sum(0).reshape(-1),
        policy=policy_of(x),
        occupancy=x,
        multipliers=multipliers,
        budgets=d,
    )


__all__ = ["FiniteOptimum", "InfeasibleBudgets", "budgets_of", "solve"]
