"""Projection-based Constrained Policy Optimization (Yang, Rosca, Narasimhan, Ramadge 2020, ICLR; steps
cited by name: docs/references.md). With ``g``, ``b`` the surrogates' gradients, ``H`` the Fisher matrix,
``c`` = J_c - d per step (natural_gradient.per_step_constraint) and ``delta`` = ``target_kl``:

1. reward improvement: TRPO's ``x_r = sqrt(2 delta / g^T H^-1 g) H^-1 g``;
2. projection onto ``{x : c + b^T x <= 0}`` in the metric ``L`` (``H`` for ``algo.projection: kl``, ``I``
   for ``l2``): ``x = x_r - max(0, (c + b^T x_r) / (b^T L^-1 b)) L^-1 b``.

A feasible step is not moved; an infeasible iterate is projected onto the boundary (no recovery rule, no
line search, as in the paper).
"""

from __future__ import annotations

import math
from typing import Callable, ClassVar, Literal

import torch

from cmdp_rl.algos.base import check_finite, single_constraint
from cmdp_rl.algos.multiplier import EpisodeCost
from cmdp_rl.algos.trust_region.natural_gradient import (
    STATS,
    NaturalGradient,
    NaturalGradientConfig,
    assign,
    conjugate_gradient,
    per_step_constraint,
)
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys

_EPS = 1e-12


@options
class PCPOConfig(NaturalGradientConfig):
    """PCPO (Yang et al. 2020): a TRPO reward step, then a projection onto the linearised constraint."""

    name: str = "pcpo"
    constraints: ClassVar[int] = 1  # one constraint (single_constraint)
    projection: Literal["kl", "l2"] = "kl"
    reads_raw_cost: ClassVar[bool] = True


def projected_step(
    g: torch.Tensor,
    b: torch.Tensor,
    c: float,
    delta: float,
    h_solve: Callable[[torch.Tensor], torch.Tensor],
    projection: str,
) -> tuple[torch.Tensor, float]:
    """PCPO's step ``x`` and the projection's coefficient (0: feasible); ``h_solve(v)`` approximates ``H^-1 v``."""
    h_inv_g = h_solve(g)
    q = g.dot(h_inv_g).item()
    x_r = math.sqrt(2 * delta / q) * h_inv_g if q > _EPS else torch.zeros_like(g)  # reward step
    l_inv_b = h_solve(b) if projection == "kl" else b
    s = b.dot(l_inv_b).item()
    violation = c + b.dot(x_r).item()
    if s <= _EPS or violation <= 0.0:  # feasible already (or no cost gradient to project along)
        return x_r, 0.0
    coef = violation / s
    return x_r - coef * l_inv_b, coef  # projection step


class PCPO(NaturalGradient):
    name = "pcpo"
    stats = (*STATS, "projection_coef", "surr_reward_change", "surr_cost_change")  # projection_coef 0: feasible

    def __init__(self, cfg: PCPOConfig, agent: Agent) -> None:
        self.cost_limit = single_constraint(
            cfg.cost_limit, agent, "pcpo", "pcpo projects onto one linearised constraint"
        )
        super().__init__(cfg, agent)

    def policy_step(
        self,
        units: dict[str, torch.Tensor],
        episode_cost: float,
        episode_length: float,
        estimate: EpisodeCost | None = None,
    ) -> dict[str, float]:
        cfg, params = self.cfg, self.policy_params
        surrogates, surr_values, g, b, fvp = self.linearise(units, units[keys.ADVANTAGE])
        c = per_step_constraint(episode_cost, self.cost_limit, episode_length)
        check_finite(reward_gradient=g.norm(), cost_gradient=b.norm(), c=c)
        step, coef = projected_step(
            g, b, c, cfg.target_kl, lambda v: conjugate_gradient(fvp, v, cfg.cg_iters), cfg.projection
        )
        with torch.no_grad():
            assign(params, torch.nn.utils.parameters_to_vector(params) + step)
            new_reward, new_cost, new_kl = (t.item() for t in surrogates())
        check_finite(kl=new_kl)
        changes = {"surr_reward_change": new_reward - surr_values[0], "surr_cost_change": new_cost - surr_values[1]}
        return {"kl": new_kl, "projection_coef": coef, **changes, "entropy": self.entropy(units)}


register("algo", "pcpo", PCPOConfig, PCPO)
