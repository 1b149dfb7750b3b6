"""First Order Constrained Optimization in Policy Space (Zhang, Vuong, Ross, 2020, NeurIPS; Theorem 1
and Algorithm 1, cited by name: docs/references.md). Two first-order steps per iteration:

1. The optimal non-parametric update (Theorem 1) of ``max E[A_r]  s.t.  J_c + E[A_c] / (1 - gamma) <= d,
   E_s[KL(pi || pi_k)[s]] <= delta``: ``pi* = pi_k exp((A_r - nu A_c) / lambda) / Z(s)``.
2. Its projection onto the parametric policies, by the gradient of (``log Z`` does not depend on theta)::

       L(theta) = E_s[ KL(pi_theta || pi_k)[s]
                      - (1 / lambda) E_{a ~ pi_k}[ pi_theta(a|s) / pi_k(a|s) (A_r - nu A_c) ] ]

   with the indicator ``1{KL(pi_theta || pi_k)[s] <= delta}``: a state out of the trust region stops
   pulling. At ``theta_k`` this is a policy gradient (tests/test_focops.py checks it by hand).

``nu <- clip(nu + lr (J_c - d), 0, max)`` before the policy update (``algo.multiplier``); the epochs stop
once a minibatch's mean KL exceeds ``delta`` (Algorithm 1 checks per epoch). One cost signal.
"""

from __future__ import annotations

from dataclasses import field
from typing import ClassVar

import torch
from tensordict import TensorDictBase
from torch.distributions import Distribution, kl_divergence

from cmdp_rl.algos.base import single_constraint
from cmdp_rl.algos.multiplier import EpisodeCost, EpisodeCostEstimate, logged_multiplier, step
from cmdp_rl.algos.multiplier_options import DualOptions, MultiplierConfig
from cmdp_rl.algos.ppo import PPO, PPOConfig
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import PositiveFloat, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys


@options
class FOCOPSConfig(PPOConfig):
    """FOCOPS (Zhang, Vuong, Ross 2020). ``clip_epsilon`` is not read: the KL term bounds the step."""

    name: str = "focops"
    deploys: ClassVar[str] = "mixture"  # deploy.policy=auto (AlgoConfig.deploys)
    constraints: ClassVar[int] = 1  # one constraint (single_constraint)
    temperature: PositiveFloat = 1.5  # lambda of Theorem 1
    target_kl: PositiveFloat = 0.02  # delta: the per-state indicator's bound and the early stop
    # nu, the paper's: a step of 0.01 and a clamp at 2.
    multiplier: MultiplierConfig = field(default_factory=lambda: DualOptions(lr=0.01, max=2.0))


def focops_terms(
    dist: Distribution,
    old_dist: Distribution,
    action: torch.Tensor,
    old_log_prob: torch.Tensor,
    adv: torch.Tensor,
    temperature: float,
    delta: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """FOCOPS's loss per state, ``KL(pi_theta || pi_k)[s] - ratio adv / temperature`` where ``KL <= delta``, and KL."""
    kl = kl_divergence(dist, old_dist).reshape(adv.shape)
    ratio = (dist.log_prob(action) - old_log_prob).reshape(adv.shape).exp()
    inside = (kl.detach() <= delta).to(adv.dtype)
    return (kl - ratio * adv / temperature) * inside, kl


STATS = ("loss_pi", "loss_v", "loss_vc", "entropy", "kl", "outside_fraction")


class FOCOPS(PPO):
    name = "focops"
    # kl: the mean exact KL(pi_theta || pi_k); outside_fraction: states past delta (masked out).
    stats = STATS

    def __init__(self, cfg: FOCOPSConfig, agent: Agent) -> None:
        cost_limit = single_constraint(cfg.cost_limit, agent, "focops", "focops has one cost multiplier nu")
        super().__init__(cfg, agent)
        self.kl_limit = cfg.target_kl  # Algorithm 1 stops at delta itself, not PPO's 1.5 delta
        self.multiplier = cfg.multiplier.build(cost_limit)
        self.episode_cost = EpisodeCostEstimate()  # J_c, measured on each batch before the policy advantage

    def update_multiplier(self, estimate: EpisodeCost) -> None:
        step(self.multiplier, estimate)

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
        return batch.get(keys.ADVANTAGE) - self.multiplier.value * batch.get(keys.COST_ADVANTAGE)

    def policy_terms(self, dist: Distribution, mb: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict]:
        """:func:`focops_terms`, with the exact KL from ``pi_k`` (logged, and stopped on) and the states outside."""
        head = self.agent.actor.head
        old_dist = head.dist({k: mb[k] for k in head.param_keys})  # pi_k, as it acted
        taken = (mb[keys.ACTION], mb[keys.LOG_PROB], mb[keys.POLICY_ADVANTAGE])
        terms, kl = focops_terms(dist, old_dist, *taken, self.cfg.temperature, self.cfg.target_kl)
        with torch.no_grad():
            diagnostics = {"kl": kl, "kl_stop": kl, "outside_fraction": (kl > self.cfg.target_kl).float()}
        return terms, diagnostics

    def update_keys(self, batch: TensorDictBase) -> list:
        return [*super().update_keys(batch), *self.agent.actor.head.param_keys]


register("algo", "focops", FOCOPSConfig, FOCOPS)
