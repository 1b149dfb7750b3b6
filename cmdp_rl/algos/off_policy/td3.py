"""TD3 and TD3-Lagrangian (``algo=td3``, ``algo=td3_lag``): Fujimoto, van Hoof, Meger 2018, "Addressing
Function Approximation Error in Actor-Critic Methods": clipped double Q-learning (eq. 10), target policy
smoothing (eq. 14), delayed policy and target updates (Algorithm 1), the deterministic policy gradient on
Q_1. The ``_lag`` variant ascends ``Q_1 - sum_k lambda_k Q_c,k`` with SAC-Lagrangian's multiplier. Noise
is in units of the box's half-width.
"""

from __future__ import annotations

from typing import ClassVar

import torch

from cmdp_rl.algos.off_policy.common import STATS, LagrangeFields, OffPolicy, OffPolicyConfig, TargetCritics
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import NonNegativeFloat, PositiveInt, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.policies.squashed import Q_REWARD


@options
class TD3Config(OffPolicyConfig):
    """TD3 (Fujimoto et al. 2018)."""

    name: str = "td3"
    policy_delay: PositiveInt = 2  # critic steps per actor (and target) step
    target_noise: NonNegativeFloat = 0.2  # std of the target action's smoothing noise
    noise_clip: NonNegativeFloat = 0.5  # the smoothing noise is clipped to +- this
    exploration_noise: NonNegativeFloat = 0.1  # std of the behaviour policy's Gaussian noise
    actor_head: ClassVar[str] = "deterministic"  # OffPolicyConfig.shape_agent


@options
class TD3LagConfig(TD3Config, LagrangeFields):
    """TD3 with the Lagrangian of SAC-Lagrangian."""

    name: str = "td3_lag"
    deploys: ClassVar[str] = "mixture"  # deploy.policy=auto (AlgoConfig.deploys)


class TD3(OffPolicy):
    name = "td3"
    stats = STATS

    def __init__(self, cfg: TD3Config, agent: Agent) -> None:
        super().__init__(cfg, agent)
        self.target_actor = TargetCritics({"actor": agent.actor.head.net})

    def mu(self, x: torch.Tensor, target: bool = False) -> torch.Tensor:
        """The deterministic action on features ``x``, in the [-1, 1] units (``tanh(net)``)."""
        net = self.target_actor.target["actor"] if target else self.agent.actor.head.net
        return torch.tanh(net(x))

    def policy_action(self, x: torch.Tensor) -> torch.Tensor:
        return self.mu(x)

    def next_action(self, x_next: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        cfg = self.cfg
        action = self.mu(x_next, target=True)
        noise = (torch.randn_like(action) * cfg.target_noise).clamp(-cfg.noise_clip, cfg.noise_clip)  # eq. 14
        return (action + noise).clamp(-1.0, 1.0), torch.zeros(())  # noise in half-widths, clipped to the box

    def actor_step(self, x: torch.Tensor) -> dict[str, torch.Tensor] | None:
        if self.gradient_steps % self.cfg.policy_delay:
            return None  # delayed policy updates (Algorithm 1)
        q_pen, q_c = self.penalised_q(x, self.mu(x), reward_critics=Q_REWARD[:1])
        loss_pi = -q_pen.mean()  # the deterministic policy gradient on Q_1 (Algorithm 1)
        self.actor_opt.zero_grad(set_to_none=True)
        loss_pi.backward(inputs=self.actor_params)  # the actor's loss moves the actor only
        self.actor_opt.step()
        self.target_actor.soft_update(self.cfg.tau)
        return {"loss_pi": loss_pi.detach(), "q_cost_k": q_c.detach().mean(0)}

    def state_dict(self) -> dict:
        return {**super().state_dict(), "target_actor": self.target_actor.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.target_actor.load_state_dict(state["target_actor"])


register("algo", "td3", TD3Config, TD3)
register("algo", "td3_lag", TD3LagConfig, TD3)
