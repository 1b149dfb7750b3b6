"""Policy heads: the actor and the reward and cost critics, keyed by TensorDict entries."""

from __future__ import annotations

from dataclasses import dataclass, field

from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import ProbabilisticActor

from cmdp_rl import keys
from cmdp_rl.config import PolicyConfig
from cmdp_rl.envs import VecEnv
from cmdp_rl.normalization import Normalizers
from cmdp_rl.policies.mlp import make_actor, make_critic


@dataclass
class ActorCritic:
    """The three networks every algorithm trains: actor, reward critic, cost critic; and the running
    normalization statistics they use (no parameters; saved with them, see normalization.py)."""

    actor: ProbabilisticActor
    critic: TensorDictModule
    cost_critic: TensorDictModule
    normalizers: Normalizers = field(default_factory=Normalizers)

    def modules(self) -> nn.ModuleDict:
        return nn.ModuleDict({
            "actor": self.actor, "critic": self.critic, "cost_critic": self.cost_critic,
            "normalizers": self.normalizers,
        })


def make_actor_critic(cfg: PolicyConfig, env: VecEnv, normalizers: Normalizers | None = None) -> ActorCritic:
    """``normalizers`` (see :func:`~cmdp_rl.normalization.make_normalizers`): its observation
    normalizer, if any, goes in front of all three networks."""
    if cfg.name != "mlp":
        raise ValueError(f"policy.name: unknown policy {cfg.name!r}; allowed: ['mlp']")
    norm = normalizers if normalizers is not None else Normalizers()
    return ActorCritic(
        actor=make_actor(cfg, env.obs_dim, env.action_low, env.action_high, norm.obs).to(env.device),
        critic=make_critic(cfg, env.obs_dim, keys.VALUE, norm.obs).to(env.device),
        cost_critic=make_critic(cfg, env.obs_dim, keys.COST_VALUE, norm.obs).to(env.device),
        normalizers=norm.to(env.device),
    )


__all__ = ["ActorCritic", "make_actor_critic"]
