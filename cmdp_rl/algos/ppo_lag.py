"""Reward-penalty PPO and PPO-Lagrangian: PPO's update (``ppo.ppo_update``) on a penalised advantage. As
in SafePO's PPO-Lag, ``update_multiplier`` moves lambda once per iteration from the measured J_c
(multiplier.py), before ``policy_advantage`` gives the advantage the surrogate reads.

- Penalty: PPO on ``r - lambda c``, lambda fixed (one, or one per cost); GAE is linear in the reward, so
  its advantage is exactly ``A_r - sum_k lambda_k A_c,k``, the critics kept separate.
- Lagrangian: ``A = (A_r - sum_k lambda_k A_c,k) / (1 + sum_k lambda_k)`` (in ``A_r``'s scale however
  many multipliers grow), one controller per constraint. pid_lag is ppo_lag with ``multiplier.kind: pid``.
"""

from __future__ import annotations

from dataclasses import field
from typing import ClassVar

import torch
from tensordict import TensorDictBase

from cmdp_rl.algos.base import PerConstraint, per_constraint
from cmdp_rl.algos.multiplier import EpisodeCost, EpisodeCostEstimate, Multipliers, logged_multiplier
from cmdp_rl.algos.multiplier_options import AdvantageScale, LogDualOptions, MultiplierConfig, PIDOptions
from cmdp_rl.algos.ppo import PPO, PPOConfig
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.advantages import standardized


def penalised(batch: TensorDictBase | dict[str, torch.Tensor], lams: list[float]) -> torch.Tensor:
    """``A_r - sum_k lambda_k A_c,k`` (with K = 1 exactly ``A_r - lambda A_c``)."""
    adv, cost_adv = batch.get(keys.ADVANTAGE), batch.get(keys.COST_ADVANTAGE)
    for k, lam in enumerate(lams):
        adv = adv - lam * cost_adv[..., k : k + 1]
    return adv


def lagrangian_advantage(
    batch: TensorDictBase | dict[str, torch.Tensor], lams: list[float], scale: str = "raw"
) -> torch.Tensor:
    """The Lagrangian's policy advantage ``(A_r - sum_k lambda_k A_c,k) / (1 + sum_k lambda_k)``.

    ``scale``: ``raw`` weighs the advantages in their own units; ``standardized`` first brings ``A_r``
    and each ``A_c,k`` to mean 0 and std 1 over the batch, so lambda = 1 weighs a cost as much as the
    reward whatever their units, and with the budget-relative dual step scaling the costs and budgets
    leaves the run unchanged (why, measured on PointGoal1: docs/constraint_satisfaction.md).
    """
    if scale == "standardized":
        adv, cost_adv = batch.get(keys.ADVANTAGE), batch.get(keys.COST_ADVANTAGE)
        rows = tuple(range(cost_adv.dim() - 1))
        batch = {keys.ADVANTAGE: standardized(adv), keys.COST_ADVANTAGE: standardized(cost_adv, rows)}
    return penalised(batch, lams) / (1.0 + sum(lams))


@options
class PenaltyConfig(PPOConfig):
    """PPO on r - penalty * c with a fixed exchange rate."""

    name: str = "penalty"
    penalty: PerConstraint = 1.0  # one lambda for every cost, or a list of K
    # Its fixed lambda prices raw cost: cost scaling would change what the number means.
    reads_raw_cost: ClassVar[bool] = True


@options
class PPOLagConfig(PPOConfig):
    """PPO-Lagrangian (Ray, Achiam, Amodei 2019): lambda by ``multiplier`` (multiplier.py)."""

    name: str = "ppo_lag"
    deploys: ClassVar[str] = "mixture"  # deploy.policy=auto (AlgoConfig.deploys)
    multiplier: MultiplierConfig = field(default_factory=LogDualOptions)
    advantage_scale: AdvantageScale = "standardized"  # lambda weighs: raw: A_r and A_c; standardized: each standardised


@options
class PIDLagConfig(PPOLagConfig):
    """pid_lag: ppo_lag with a PID multiplier (Stooke et al. 2020), the preset of configs/algo/pid_lag.yaml."""

    name: str = "pid_lag"
    multiplier: MultiplierConfig = field(default_factory=PIDOptions)
    advantage_scale: AdvantageScale = "raw"  # its gains were set on raw advantages (not yet measured on both)


class PenaltyPPO(PPO):
    name = "penalty"

    def __init__(self, cfg: PenaltyConfig, agent: Agent) -> None:
        super().__init__(cfg, agent)
        self.penalties = per_constraint(cfg.penalty, "algo.penalty", agent.cost_names)

    @property
    def lagrange_multiplier(self) -> float | list[float]:
        return logged_multiplier(self.penalties)

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        return penalised(batch, self.penalties)


class PPOLagrangian(PPO):
    name = "ppo_lag"

    def __init__(self, cfg: PPOLagConfig, agent: Agent) -> None:
        super().__init__(cfg, agent)
        limits = per_constraint(cfg.cost_limit, "algo.cost_limit", agent.cost_names)
        self.multiplier = Multipliers(cfg.multiplier.build, limits)
        self.episode_cost = EpisodeCostEstimate()  # J_c, measured on each batch before the policy advantage
        if cfg.multiplier.kind == "regularized":
            # The policy side of Ding et al.'s regularised Lagrangian: an entropy bonus tau.
            self.entropy_coef = cfg.entropy_coef + cfg.multiplier.tau

    def update_multiplier(self, estimate: EpisodeCost) -> None:
        self.multiplier.update(estimate)

    def before_advantage(self, batch: TensorDictBase) -> None:
        self.update_multiplier(self.episode_cost.update(batch))

    @property
    def lagrange_multiplier(self) -> float | list[float]:
        return logged_multiplier(self.multiplier.values)

    def state_dict(self) -> dict:
        own = {"episode_cost": self.episode_cost.state_dict(), "multiplier": self.multiplier.state_dict()}
        return {**super().state_dict(), **own}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.episode_cost.load_state_dict(state["episode_cost"])
        self.multiplier.load_state_dict(state["multiplier"])

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        return lagrangian_advantage(batch, self.multiplier.values, self.cfg.advantage_scale)


register("algo", "penalty", PenaltyConfig, PenaltyPPO)
register("algo", "ppo_lag", PPOLagConfig, PPOLagrangian)
register("algo", "pid_lag", PIDLagConfig, PPOLagrangian)
