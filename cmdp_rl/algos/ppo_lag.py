"""Reward-penalty PPO and PPO-Lagrangian (dual ascent, PID, or a last-iterate update): PPO's
clipped update (``ppo.ppo_update``) on a penalised advantage. A variant here is two methods, as in
SafePO's PPO-Lag: ``update_multiplier`` moves lambda once per iteration from the measured episode
cost, before the policy update, and ``policy_advantage`` is the advantage the surrogate reads.

- Penalty: PPO on the reward ``r - lambda c`` with a fixed lambda. GAE is linear in the reward, so
  with ``V = V_r - lambda V_c`` its advantage is exactly ``A_r - lambda A_c``; the two critics stay
  separate.
- Lagrangian: ``A = (A_r - lambda A_c) / (1 + lambda)``, lambda by a controller on the measured
  ``J_c - d`` once per iteration, before the policy update: projected dual ascent, PID (Stooke,
  Achiam, Abbeel 2020; multiplier.py), or the last-iterate updates of multiplier.py
  (``algo.multiplier.kind``, multiplier.py). pid_lag is ppo_lag with ``multiplier.kind: pid``.

K constraints (an env reporting K costs): one multiplier per constraint, each moved by its own
``J_c,k - d_k`` (``multiplier.Multipliers``), and the advantage is
``(A_r - sum_k lambda_k A_c,k) / (1 + sum_k lambda_k)``: the same normalisation as K = 1, which it
is exactly (the penalised advantage's scale stays that of ``A_r`` however many multipliers grow).
Penalty takes one lambda for every cost or a list of K: ``A_r - sum_k lambda_k A_c,k``.
"""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, ClassVar

import torch
from tensordict import TensorDictBase

from cmdp_rl.algos.base import PerConstraint, per_constraint
from cmdp_rl.algos.multiplier import AdvantageScale, EpisodeCost, MultiplierConfig, Multipliers
from cmdp_rl.algos.ppo import PPO, PPOConfig, logged_multiplier
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.advantages import standardized

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig


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

    ``scale``: ``raw`` weighs the advantages in their own units; ``standardized`` first brings
    ``A_r`` and each ``A_c,k`` to mean 0 and standard deviation 1 over the batch, so that lambda = 1
    weighs a cost signal as much as the reward's whatever either is measured in. On PointGoal1 the
    cost advantage's spread is 10-30 times the reward's, so in raw units any lambda above about 0.1
    already hands the policy's update to the cost (docs/constraint_satisfaction.md). OmniSafe
    standardises the reward advantage and centres the cost advantage; both are standardised here so
    that, with the budget-relative dual step, scaling the costs (and the budgets) by any factor
    leaves the whole run unchanged.
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
    """PPO-Lagrangian (Ray, Achiam, Amodei 2019): lambda adapted by projected dual ascent, PID, or
    one of the last-iterate updates (``multiplier``, multiplier.py)."""

    name: str = "ppo_lag"
    deploys: ClassVar[str] = "mixture"  # deploy.policy=auto (AlgoConfig.deploys)
    multiplier: MultiplierConfig = field(default_factory=MultiplierConfig)
    advantage_scale: AdvantageScale = "raw"  # lambda weighs: raw: A_r and A_c; standardized: each standardised

    def check(self, run: RunConfig) -> None:
        super().check(run)
        self.multiplier.check()


@options
class PIDLagConfig(PPOLagConfig):
    """pid_lag: ppo_lag with lambda from a PID controller (Stooke, Achiam, Abbeel 2020), its gains
    the tested setting of docs/pid_and_cpo.md. A preset, not an algorithm: the class exists only so
    that a config that names pid_lag without a multiplier node (a dict, a script) gets the
    preset's node, as configs/algo/pid_lag.yaml gives Hydra."""

    name: str = "pid_lag"
    multiplier: MultiplierConfig = field(default_factory=lambda: MultiplierConfig(kind="pid"))


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
    """Lambda from the controllers ``algo.multiplier`` builds (multiplier.py), one per constraint;
    the policy update is the same for every kind."""

    name = "ppo_lag"

    def __init__(self, cfg: PPOLagConfig, agent: Agent) -> None:
        super().__init__(cfg, agent)
        limits = per_constraint(cfg.cost_limit, "algo.cost_limit", agent.cost_names)
        # One multiplier per constraint (multiplier.Multipliers), each with its own budget d_k.
        self.multiplier = Multipliers(cfg.multiplier.build, limits)
        if cfg.multiplier.kind == "regularized":
            # The policy side of Ding et al.'s regularised Lagrangian: an entropy bonus tau
            # (on the standardised policy advantage, so tau is in its units).
            self.entropy_coef = cfg.entropy_coef + cfg.multiplier.tau

    @property
    def lagrange_multiplier(self) -> float | list[float]:
        return logged_multiplier(self.multiplier.values)

    def update_multiplier(self, estimate: EpisodeCost) -> None:
        # Dual ascent on the Lagrangian J_r - lambda (J_c - d) (Ray, Achiam, Amodei 2019), by default:
        # lambda <- max(0, lambda + lr (J_c - d) / s), s = d with multiplier.scale=budget, else 1
        # (multiplier.DualAscent; PID or a last-iterate update by algo.multiplier.kind), one per constraint,
        # on the batch's J_c estimate (multiplier.EpisodeCostEstimate).
        self.multiplier.update(estimate.costs)

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        # (A_r - lambda A_c) / (1 + lambda): the surrogate of the Lagrangian, scaled back to A_r's units.
        return lagrangian_advantage(batch, self.multiplier.values, self.cfg.advantage_scale)

    def state_dict(self) -> dict:
        return {**super().state_dict(), "multiplier": self.multiplier.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.multiplier.load_state_dict(state["multiplier"])


register("algo", "penalty", PenaltyConfig, PenaltyPPO)
register("algo", "ppo_lag", PPOLagConfig, PPOLagrangian)
register("algo", "pid_lag", PIDLagConfig, PPOLagrangian)
