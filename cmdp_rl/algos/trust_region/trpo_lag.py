"""TRPO-Lagrangian (Ray, Achiam, Amodei 2019, "Benchmarking Safe Exploration in Deep Reinforcement
Learning": the Lagrangian baselines, docs/references.md): TRPO's step (Schulman et al. 2015, eq. 14,
Appendix C) ``x = sqrt(2 delta / g^T H^-1 g) H^-1 g`` on ppo_lag's Lagrangian advantage, then a line search
for the first fraction within delta whose Lagrangian surrogate improves; one multiplier per constraint
(``algo.multiplier``), moved once per iteration before the step.
"""

from __future__ import annotations

import math
from dataclasses import field
from typing import ClassVar, Optional, Sequence

import torch

from cmdp_rl.algos.base import check_finite, per_constraint
from cmdp_rl.algos.multiplier import EpisodeCost, Multipliers
from cmdp_rl.algos.multiplier_options import AdvantageScale, LogDualOptions, MultiplierConfig
from cmdp_rl.algos.ppo_lag import lagrangian_advantage
from cmdp_rl.algos.trust_region.cpo import CPOConfig
from cmdp_rl.algos.trust_region.natural_gradient import (
    NO_STEP,
    STATS,
    NaturalGradient,
    conjugate_gradient,
    line_search,
)
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import options
from cmdp_rl.policies.agent import Agent


@options
class TRPOLagConfig(CPOConfig):
    """CPO's trust region and line search, ppo_lag's multiplier (``regularized`` regularises the dual only)."""

    name: str = "trpo_lag"
    multiplier: MultiplierConfig = field(default_factory=LogDualOptions)
    advantage_scale: AdvantageScale = "standardized"  # lambda weighs: raw: A_r and A_c; standardized: each standardised
    # lambda reads J_c from the episodes' raw cost sums; the policy advantage may be scaled.
    reads_raw_cost: ClassVar[bool] = False
    deploys: ClassVar[str] = "mixture"  # deploy.policy=auto (AlgoConfig.deploys)
    constraints: ClassVar[Optional[int]] = None  # one multiplier per cost: any K


class TRPOLagrangian(NaturalGradient):
    name = "trpo_lag"
    # surr_reward_change: of the Lagrangian surrogate; step_fraction: of the full step accepted (0: none).
    stats = (*STATS, "step_fraction", "surr_reward_change", "surr_cost_change")

    def __init__(self, cfg: TRPOLagConfig, agent: Agent) -> None:
        super().__init__(cfg, agent)
        limits = per_constraint(cfg.cost_limit, "algo.cost_limit", agent.cost_names)
        self.multiplier = Multipliers(cfg.multiplier.build, limits)

    def policy_step(
        self,
        units: dict[str, torch.Tensor],
        episode_cost: float | Sequence[float],
        episode_length: float,
        estimate: EpisodeCost | None = None,
    ) -> dict[str, float]:
        """``episode_cost``: J_c, or K numbers with K constraints; ``estimate``: the measurement they come from."""
        cfg, params = self.cfg, self.policy_params
        costs = [episode_cost] if isinstance(episode_cost, (int, float)) else episode_cost
        lams = self.multiplier.update(estimate if estimate is not None else costs)
        # The cost surrogate is logged only (with K > 1: the mean over the constraints').
        adv = lagrangian_advantage(units, lams, cfg.advantage_scale)
        surrogates, surr_values, g, _, fvp = self.linearise(units, adv, cost_gradient=False)
        h_inv_g = conjugate_gradient(fvp, g, cfg.cg_iters)
        q = g.dot(h_inv_g).item()
        check_finite(gradient=g.norm(), q=q)
        if q <= 0.0:  # no gradient (e.g. all advantages equal): nothing to follow
            return {**NO_STEP, "entropy": self.entropy(units)}
        step = math.sqrt(2 * cfg.target_kl / q) * h_inv_g  # the trust region's boundary along H^-1 g (App. C)
        search = (cfg.target_kl, cfg.line_search_steps, cfg.backtrack_coef)
        accepted = line_search(params, step, surrogates, surr_values, *search, lambda d_reward, d_cost: d_reward > 0)
        return {"entropy": self.entropy(units), **accepted}


register("algo", "trpo_lag", TRPOLagConfig, TRPOLagrangian)
