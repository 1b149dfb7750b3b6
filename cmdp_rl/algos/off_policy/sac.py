"""SAC and SAC-Lagrangian on a replay buffer (``algo=sac``, ``algo=sac_lag``). SAC with automatic entropy
tuning: Haarnoja et al. 2018b, "Soft Actor-Critic Algorithms and Applications" (arXiv:1812.05905): twin
soft Q-critics (eq. 5), the policy loss (eq. 7, reparameterised: eqs. 8-9; tanh squashing: Appendix C),
the temperature (eq. 18) towards -dim(A) by default (Appendix D), log pi in the squashed [-1, 1] units so
that it means the same on any box. SAC-Lagrangian ascends ``min_j Q_j - alpha log pi - sum_k lambda_k Q_c,k``
(Ha et al. 2020, "Learning to Walk in the Real World with Minimal Human Effort"), lambda as off_policy.common.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal, Union

import torch
from torch.nn import functional as F

from cmdp_rl.algos.off_policy.common import STATS, LagrangeFields, OffPolicy, OffPolicyConfig
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import AUTO, Bool, Field, PositiveFloat, finite, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys

LOG_2, HALF_LOG_2PI = math.log(2.0), 0.5 * math.log(2.0 * math.pi)


@options
class SACConfig(OffPolicyConfig):
    """SAC (Haarnoja et al. 2018b) with automatic entropy tuning."""

    name: str = "sac"
    alpha_init: PositiveFloat = 1.0  # the initial temperature
    alpha_lr: PositiveFloat = 3e-4
    autotune: Bool = True  # false: alpha stays alpha_init
    # "auto": -dim(A), in the squashed action's units (module docstring)
    target_entropy: Annotated[
        Union[Annotated[float, finite()], Literal["auto"]], Field(description="a number or 'auto'")
    ] = AUTO


@options
class SACLagConfig(SACConfig, LagrangeFields):
    """SAC-Lagrangian (Ha et al. 2020): lambda on the cost critic against the discounted budget."""

    name: str = "sac_lag"
    deploys: ClassVar[str] = "mixture"  # deploy.policy=auto (AlgoConfig.deploys)


class SAC(OffPolicy):
    name = "sac"
    stats = (*STATS, "alpha", "entropy")

    def __init__(self, cfg: SACConfig, agent: Agent) -> None:
        super().__init__(cfg, agent)
        head = agent.actor.head
        self.target_entropy = -float(head.low.numel()) if cfg.target_entropy == AUTO else float(cfg.target_entropy)
        self.log_alpha = torch.tensor(math.log(cfg.alpha_init), device=head.low.device, requires_grad=True)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=cfg.alpha_lr)

    def sample(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised action in the squashed [-1, 1] units, ``tanh(u)``, ``u ~ N(mu, sigma)``, and its
        log pi ``[B, 1]``: ``log N(u) - sum_i log(1 - tanh(u_i)^2)`` (Haarnoja et al. 2018b, eq. 21). The
        head's TanhNormal gives the same density, slower (docs/off_policy.md, Speed)."""
        params = self.agent.actor.head(x)
        mu, std = params[keys.LOC], params[keys.SCALE]
        eps = torch.randn_like(mu)
        u = mu + std * eps
        # log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)), exact and finite for large |u|
        log_pi = (-0.5 * eps.pow(2) - std.log() - HALF_LOG_2PI - 2.0 * (LOG_2 - u - F.softplus(-2.0 * u))).sum(
            -1, keepdim=True
        )
        return torch.tanh(u), log_pi

    def policy_action(self, x: torch.Tensor) -> torch.Tensor:
        return self.sample(x)[0]

    def next_action(self, x_next: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        action, log_pi = self.sample(x_next)
        return action, -self.log_alpha.exp() * log_pi  # the soft value's entropy bonus (eq. 3)

    def actor_step(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        alpha = self.log_alpha.exp().detach()
        action, log_pi = self.sample(x)
        q_pen, q_c = self.penalised_q(x, action)
        loss_pi = (alpha * log_pi - q_pen).mean()  # eq. 7, with the Lagrangian's cost term
        self.actor_opt.zero_grad(set_to_none=True)
        loss_pi.backward(inputs=self.actor_params)  # the actor's loss moves the actor only
        self.actor_opt.step()
        if self.cfg.autotune:  # eq. 18: J(alpha) = E[-alpha (log pi + target entropy)], on log alpha
            loss_alpha = -(self.log_alpha * (log_pi.detach() + self.target_entropy)).mean()
            self.alpha_opt.zero_grad(set_to_none=True)
            loss_alpha.backward()
            self.alpha_opt.step()
        return {
            "loss_pi": loss_pi.detach(),
            "alpha": alpha,
            "entropy": -log_pi.detach().mean(),
            "q_cost_k": q_c.detach().mean(0),
        }

    def state_dict(self) -> dict:
        return {
            **super().state_dict(),
            "log_alpha": self.log_alpha.detach().clone(),
            "alpha_opt": self.alpha_opt.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.alpha_opt.load_state_dict(state["alpha_opt"])


register("algo", "sac", SACConfig, SAC)
register("algo", "sac_lag", SACLagConfig, SAC)
