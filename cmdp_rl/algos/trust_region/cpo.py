"""Constrained Policy Optimization (Achiam, Held, Tamar, Abbeel, 2017, ICML; Section 6, Algorithm 1).

Each iteration solves the approximate CPO update (eq. 11) around the policy ``pi_k`` that collected the
batch, with ``x = theta - theta_k``::

    max_x  g^T x    s.t.   c + b^T x <= 0,    1/2 x^T H x <= delta

``g``, ``b``: the reward and cost surrogates' gradients; ``H``: the Fisher matrix; ``delta``:
``algo.target_kl``. Its two-variable dual (eq. 12) has a closed form, :func:`solve_dual` (the supplement's
Theorem 2), in three cases: ``TRPO`` (the whole trust region is feasible: TRPO's step), ``CONSTRAINED``
(``x* = H^-1 (g - nu* b) / lambda*``, eq. 13) and ``RECOVERY`` (no point is feasible: the pure cost step
``x = -sqrt(2 delta / s) H^-1 b``, eq. 14). A backtracking line search then keeps the step within ``delta``
and what the case allows the cost (Algorithm 1). One constraint only: with K the dual is a QP in K + 1
variables with no closed form, and the recovery must choose which constraints to restore.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch

from cmdp_rl.algos.base import check_finite, single_constraint
from cmdp_rl.algos.multiplier import EpisodeCost
from cmdp_rl.algos.trust_region.natural_gradient import (
    STATS,
    NaturalGradient,
    NaturalGradientConfig,
    conjugate_gradient,
    fisher_vector_product,
    line_search,
    per_step_constraint,
)
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import PositiveInt, UnitOpen, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys

__all__ = ["CPO", "CPOConfig", "solve_dual", "fisher_vector_product", "TRPO", "CONSTRAINED", "RECOVERY"]


@options
class CPOConfig(NaturalGradientConfig):
    """Constrained Policy Optimization (Achiam, Held, Tamar, Abbeel 2017)."""

    name: str = "cpo"
    constraints: ClassVar[int] = 1  # one constraint (single_constraint)
    line_search_steps: PositiveInt = 10
    backtrack_coef: UnitOpen = 0.8
    reads_raw_cost: ClassVar[bool] = True


TRPO, CONSTRAINED, RECOVERY = 0, 1, 2
_EPS = 1e-8


@dataclass
class DualSolution:
    """The case and the optimal dual variables of the CPO subproblem."""

    case: int
    lam: float  # trust-region multiplier; 0 in RECOVERY (the reward is ignored there)
    nu: float  # cost multiplier; in RECOVERY the coefficient of the pure cost step -nu H^-1 b


def solve_dual(q: float, r: float, s: float, c: float, delta: float) -> DualSolution:
    """Solve the dual of the CPO subproblem in closed form. The dual (eq. 12, K = 1) is
    ``max_{lambda >= 0, nu >= 0}  -(q - 2 r nu + s nu^2) / (2 lambda) + nu c - lambda delta`` (the paper
    prints ``lambda delta / 2``, the dual of Theorem 2's ``x^T H x <= delta``: its delta is 2 delta here).
    For fixed lambda the maximiser is ``nu = max(0, (lambda c + r) / s)``. Where that is positive,
    ``f_a(lambda) = -(A / lambda + B lambda) / 2 + r c / s`` with ``A = q - r^2 / s``, ``B = 2 delta - c^2 / s``;
    where it is 0, ``f_b(lambda) = -(q / lambda + 2 delta lambda) / 2``. Both are concave: their maximisers
    ``sqrt(A / B)`` and ``sqrt(q / (2 delta))``, projected onto their intervals, give each piece's best; the
    dual optimum is the better of the two.
    """
    if s <= _EPS:  # the cost surrogate has no gradient: nothing to trade against; plain TRPO
        return DualSolution(TRPO, math.sqrt(q / (2 * delta)) + _EPS, 0.0)
    B = 2 * delta - c * c / s
    if c < 0 and B < 0:  # |c| > sqrt(2 delta s): even the costliest point of the trust region is feasible
        return DualSolution(TRPO, math.sqrt(q / (2 * delta)) + _EPS, 0.0)
    if B < 0:  # c > sqrt(2 delta s): the cheapest point of the trust region is still infeasible
        return DualSolution(RECOVERY, 0.0, math.sqrt(2 * delta / s))
    A = max(q - r * r / s, 0.0)  # >= 0 by Cauchy-Schwarz in the H^-1 inner product
    # Intervals of lambda > 0 on which nu* > 0 (piece a) and nu* = 0 (piece b): lambda c + r > 0.
    inf = math.inf
    if abs(c) <= _EPS:
        piece_a, piece_b = ((0.0, inf), None) if r > 0 else (None, (0.0, inf))
    else:
        lam_mid = -r / c
        if c > 0:
            piece_a, piece_b = ((max(lam_mid, 0.0), inf), (0.0, lam_mid) if lam_mid > 0 else None)
        else:
            piece_a, piece_b = ((0.0, lam_mid) if lam_mid > 0 else None, (max(lam_mid, 0.0), inf))

    def f_a(lam: float) -> float:
        return -0.5 * (A / lam + B * lam) + r * c / s

    def f_b(lam: float) -> float:
        return -0.5 * (q / lam + 2 * delta * lam)

    candidates = []
    if piece_a is not None:
        lam_a = math.sqrt(A / B) if B > _EPS else inf  # B = 0: f_a increases in lambda
        lam_a = min(max(lam_a, piece_a[0], _EPS), piece_a[1])
        if math.isfinite(lam_a):
            candidates.append((f_a(lam_a), lam_a))
    if piece_b is not None:
        lam_b = min(max(math.sqrt(q / (2 * delta)), piece_b[0], _EPS), piece_b[1])
        candidates.append((f_b(lam_b), lam_b))
    _, lam = max(candidates)
    nu = max(0.0, (lam * c + r) / s)
    return DualSolution(CONSTRAINED, lam, nu)


class CPO(NaturalGradient):
    name = "cpo"
    # cpo_case: 0 trpo, 1 constrained, 2 recovery; step_fraction: of the full step accepted (0: none).
    stats = (*STATS, "cpo_case", "step_fraction", "dual_lambda", "dual_nu", "surr_reward_change", "surr_cost_change")

    def __init__(self, cfg: CPOConfig, agent: Agent) -> None:
        self.cost_limit = single_constraint(
            cfg.cost_limit, agent, "cpo", "cpo's closed-form dual handles one constraint"
        )
        super().__init__(cfg, agent)
        self.nu = 0.0

    @property
    def lagrange_multiplier(self) -> float:
        """The dual's cost multiplier nu of the last step."""
        return self.nu

    def policy_step(
        self,
        units: dict[str, torch.Tensor],
        episode_cost: float,
        episode_length: float,
        estimate: EpisodeCost | None = None,
    ) -> dict[str, float]:
        """Solve the CPO subproblem on the units and take the step the line search accepts (or none)."""
        cfg, params = self.cfg, self.policy_params
        surrogates, surr_values, g, b, fvp = self.linearise(units, units[keys.ADVANTAGE])
        h_inv_g = conjugate_gradient(fvp, g, cfg.cg_iters)
        h_inv_b = conjugate_gradient(fvp, b, cfg.cg_iters)
        q, r, s = g.dot(h_inv_g).item(), g.dot(h_inv_b).item(), b.dot(h_inv_b).item()
        c = per_step_constraint(episode_cost, self.cost_limit, episode_length)
        check_finite(reward_gradient=g.norm(), cost_gradient=b.norm(), q=q, r=r, s=s, c=c)

        sol = solve_dual(q, r, s, c, cfg.target_kl)
        if sol.case == RECOVERY:
            step = -sol.nu * h_inv_b  # eq. 14
        else:
            step = (h_inv_g - sol.nu * h_inv_b) / sol.lam  # eq. 13
        self.nu = sol.nu

        # Algorithm 1's line search: in RECOVERY the cost surrogate must fall; otherwise it may rise by the
        # slack -c, if any; and a feasible policy's (c < 0) step must improve the reward surrogate too.
        def accept(d_reward: float, d_cost: float) -> bool:
            if sol.case == RECOVERY:
                return d_cost < 0
            return d_cost <= max(-c, 0.0) and (c >= 0 or d_reward > 0)

        accepted = line_search(
            params, step, surrogates, surr_values, cfg.target_kl, cfg.line_search_steps, cfg.backtrack_coef, accept
        )
        dual = {"cpo_case": sol.case, "dual_lambda": sol.lam, "dual_nu": sol.nu}
        return {**dual, "entropy": self.entropy(units), **accepted}

    def state_dict(self) -> dict:
        return {**super().state_dict(), "nu": self.nu}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.nu = float(state["nu"])


register("algo", "cpo", CPOConfig, CPO)
