"""Policy heads: the actor and the reward and cost critics, keyed by TensorDict entries."""

from __future__ import annotations

from dataclasses import dataclass

from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import ProbabilisticActor

from cmdp_rl import keys
from cmdp_rl.config import PolicyConfig
from cmdp_rl.envs import VecEnv
from cmdp_rl.policies.mlp import make_actor, make_critic


@dataclass
class ActorCritic:
    """The three networks every algorithm trains: actor, reward critic, cost critic."""

    actor: ProbabilisticActor
    critic: TensorDictModule
    cost_critic: TensorDictModule

    def modules(self) -> nn.ModuleDict:
        return nn.ModuleDict({"actor": self.actor, "critic": self.critic, "cost_critic": self.cost_critic})


def make_actor_critic(cfg: PolicyConfig, env: VecEnv) -> ActorCritic:
    if cfg.name != "mlp":
        raise ValueError(f"policy.name: unknown policy {cfg.name!r}; allowed: ['mlp']")
    return ActorCritic(
        actor=make_actor(cfg, env.obs_dim, env.action_low, env.action_high).to(env.device),
        critic=make_critic(cfg, env.obs_dim, keys.VALUE).to(env.device),
        cost_critic=make_critic(cfg, env.obs_dim, keys.COST_VALUE).to(env.device),
    )


__all__ = ["ActorCritic", "make_actor_critic"]
