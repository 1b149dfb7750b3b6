"""Constraint-Rectified Policy Optimization (Xu, Liang, Lan, 2021, ICML; Algorithm 1, cited by name:
docs/references.md). While ``J_c <= d + eta`` a step that improves the reward (PPO's clipped surrogate on
``A_r``), else one that reduces the cost (on ``-A_c``): it switches objectives, never mixes them. Clipped
PPO replaces the paper's natural-gradient steps, as its later implementations do. One cost signal.
"""

from __future__ import annotations

from typing import ClassVar

import torch
from tensordict import TensorDictBase

from cmdp_rl.algos.base import single_constraint
from cmdp_rl.algos.multiplier import EpisodeCost, EpisodeCostEstimate
from cmdp_rl.algos.ppo import PPO, STATS, PPOConfig
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import NonNegativeFloat, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys


@options
class CRPOConfig(PPOConfig):
    """CRPO (Xu, Liang, Lan 2021): reward step while J_c <= cost_limit + tolerance, else cost step."""

    name: str = "crpo"
    constraints: ClassVar[int] = 1  # one constraint (single_constraint)
    tolerance: NonNegativeFloat = 0.0  # eta of Algorithm 1


class CRPO(PPO):
    name = "crpo"
    # cost_step: 1 where the iteration took a cost step, else 0 (its mean: the fraction of cost steps).
    stats = (*STATS, "cost_step")

    def __init__(self, cfg: CRPOConfig, agent: Agent) -> None:
        self.cost_limit = single_constraint(
            cfg.cost_limit, agent, "crpo", "crpo's step switches on one constraint's slack"
        )
        super().__init__(cfg, agent)
        self.cost_step = False
        self.episode_cost = EpisodeCostEstimate()  # J_c, measured on each batch before the policy advantage

    def update_multiplier(self, estimate: EpisodeCost) -> None:
        """Algorithm 1's switch: the constraint is violated beyond the tolerance -> a cost step."""
        self.cost_step = estimate.cost > self.cost_limit + self.cfg.tolerance

    def before_advantage(self, batch: TensorDictBase) -> None:
        self.update_multiplier(self.episode_cost.update(batch))

    def state_dict(self) -> dict:
        return {**super().state_dict(), "episode_cost": self.episode_cost.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.episode_cost.load_state_dict(state["episode_cost"])

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        return -batch.get(keys.COST_ADVANTAGE) if self.cost_step else batch.get(keys.ADVANTAGE)

    def iteration_stats(self) -> dict[str, float]:
        return {"cost_step": float(self.cost_step)}


register("algo", "crpo", CRPOConfig, CRPO)
