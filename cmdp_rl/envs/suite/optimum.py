"""The exact constrained optimum of a finite-horizon CMDP (``model.py``): the occupancy LP of
``grid/optimum.py`` over the states (t, s) (Altman 1999, ch. 3; Puterman 1994, sec. 6.9). A policy's
occupancy ``x_t(s, a) = P(s_t = s, a_t = a)`` keeps the flow equations

    sum_a x_0(s, a)     = mu0(s)
    sum_a x_{t+1}(s, a) = sum_{s', a'} P(s | s', a') x_t(s', a')      for t < H - 1,

and ``pi_t(a | s) = x_t(s, a) / sum_a x_t(s, a)`` is an optimal policy; where the vertex randomises
in no (t, s), a deterministic policy is optimal. Undiscounted: the finite horizon makes the sums
finite, and they are what a run's evaluation measures.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import sparse

from cmdp_rl.envs.grid.optimum import ConstrainedOptimum, budgets_of, occupancy_lp
from cmdp_rl.envs.suite.model import FiniteCMDP


def solve(cmdp: FiniteCMDP, budgets: float | Sequence[float] | None = None) -> ConstrainedOptimum:
    """``max_pi J(pi)`` s.t. ``J_c[k](pi) <= budgets[k]`` (None: the instance's budgets; an infinite
    budget: no constraint); the optimum's arrays are ``[H, S, ...]``."""
    h, s, a, k = cmdp.horizon, cmdp.num_states, cmdp.num_actions, cmdp.num_costs
    # Variables x_t(s, a) in (t, s, a) order; step t - 1 sends P's mass into step t.
    inflow = sparse.kron(sparse.eye(h, k=-1), sparse.csr_matrix(cmdp.P.reshape(s * a, s).T))
    return occupancy_lp(
        inflow,
        np.tile(cmdp.r.reshape(-1), h),
        np.tile(cmdp.c.reshape(k, -1), (1, h)),
        np.concatenate([cmdp.mu0, np.zeros((h - 1) * s)]),
        budgets_of(budgets, k, cmdp.budgets),
        (h, s, a),
    )
