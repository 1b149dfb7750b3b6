"""Policy heads: the actor and the reward and cost critics, keyed by TensorDict entries.

``policy=mlp`` (memoryless), ``lstm``/``gru`` (recurrent state, policies/recurrent.py) or
``transformer`` (a window of the last K steps, policies/transformer.py). Algorithms see all of them
through :class:`ActorCritic`: the three networks, the module the collector steps, and how a batch
is cut into training units (single steps, or whole segments run in recurrent mode).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import ContextManager, Mapping

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.modules import ProbabilisticActor, set_recurrent_mode

from cmdp_rl import keys
from cmdp_rl.envs import VecEnv
from cmdp_rl.normalization import Normalizers
from cmdp_rl.policies.mlp import PolicyConfig, make_actor, make_critic, make_encoder
from cmdp_rl.policies.recurrent import RecurrentPolicyConfig, make_recurrent_networks
from cmdp_rl.policies.transformer import TransformerPolicyConfig, make_transformer_networks


@dataclass
class ActorCritic:
    """The three networks every algorithm trains: actor, reward critic, cost critic; and the running
    normalization statistics they use (no parameters; saved with them, see normalization.py).

    ``recurrent``: the networks carry a recurrent state of their own (LSTM/GRU). Their training
    units are then segments of ``segment_length`` consecutive steps of one env (0, or not shorter
    than the rollout: the whole rollout row), run in recurrent mode; otherwise single steps, which any minibatch may shuffle
    (a transformer's window travels with its step).
    """

    actor: ProbabilisticActor
    critic: TensorDictModuleBase
    cost_critic: TensorDictModuleBase
    normalizers: Normalizers = field(default_factory=Normalizers)
    recurrent: bool = False
    segment_length: int = 0

    def modules(self) -> nn.ModuleDict:
        return nn.ModuleDict({
            "actor": self.actor, "critic": self.critic, "cost_critic": self.cost_critic,
            "normalizers": self.normalizers,
        })

    @property
    def rollout_policy(self) -> TensorDictModuleBase:
        """What the collector steps: the actor, and with it the critics if they carry a state of
        their own, so that every network's state at every step is in the batch."""
        if not self.recurrent:
            return self.actor
        return TensorDictSequential(self.actor, self.critic, self.cost_critic)

    def sequence_mode(self) -> ContextManager:
        """The mode training and value passes call the networks in: recurrent mode for recurrent
        networks on ``[B, L]`` segments (torchrl's ``set_recurrent_mode``), else no change."""
        return set_recurrent_mode(True) if self.recurrent else contextlib.nullcontext()

    @property
    def unit_dims(self) -> int:
        """Leading dimensions of a training unit batch: 1 (steps ``[B]``) or 2 (segments ``[B, L]``)."""
        return 2 if self.recurrent else 1

    def units_tensordict(self, mb: Mapping[str, torch.Tensor]) -> TensorDict:
        """A minibatch of training units (a dict of tensors) as a TensorDict the networks read."""
        first = next(iter(mb.values()))
        return TensorDict(dict(mb), batch_size=first.shape[: self.unit_dims])

    def batch_units(self, batch: TensorDictBase) -> TensorDictBase:
        """A whole ``[N, T]`` batch as training units: ``[N T]`` steps or ``[U, L]`` segments."""
        if not self.recurrent:
            return batch.reshape(-1)
        N, T = batch.shape
        L = self.segment_length if 0 < self.segment_length < T else T
        return batch.reshape(N, T // L, L).reshape(N * (T // L), L)

    def training_units(self, data: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Entries of a ``[N, T, ...]`` batch as training units ``[U, ...]``: steps (``U = N T``) or,
        for recurrent networks, segments ``[U, L, ...]`` with ``U = N T / L``, never single steps."""
        if not self.recurrent:
            return {k: v.flatten(0, 1) for k, v in data.items()}
        out = {}
        for k, v in data.items():
            T = v.shape[1]
            L = self.segment_length if 0 < self.segment_length < T else T
            out[k] = v.unflatten(1, (T // L, L)).flatten(0, 1)
        return out


def make_actor_critic(
    cfg: PolicyConfig | RecurrentPolicyConfig | TransformerPolicyConfig,
    env: VecEnv,
    normalizers: Normalizers | None = None,
) -> ActorCritic:
    """``normalizers`` (see :func:`~cmdp_rl.normalization.make_normalizers`): its observation
    normalizer, if any, goes in front of all three networks."""
    norm = normalizers if normalizers is not None else Normalizers()
    low, high = env.action_low, env.action_high
    recurrent, segment_length = False, 0
    if isinstance(cfg, PolicyConfig) and cfg.name == "mlp":
        encoder = make_encoder(cfg, env.obs_dim, low, high, norm.obs)
        actor = make_actor(cfg, env.obs_dim, low, high, norm.obs, encoder)
        critic = make_critic(cfg, env.obs_dim, keys.VALUE, norm.obs, encoder)
        cost_critic = make_critic(cfg, env.obs_dim, keys.COST_VALUE, norm.obs, encoder)
    elif isinstance(cfg, RecurrentPolicyConfig) and cfg.name in ("lstm", "gru"):
        actor, critic, cost_critic = make_recurrent_networks(cfg, env.obs_dim, low, high, norm.obs)
        recurrent, segment_length = True, cfg.segment_length
    elif isinstance(cfg, TransformerPolicyConfig) and cfg.name == "transformer":
        actor, critic, cost_critic = make_transformer_networks(cfg, env.obs_dim, low, high, norm.obs)
    else:
        raise ValueError(f"policy.name: unknown policy {cfg.name!r} for {type(cfg).__name__}; "
                         "allowed: mlp, lstm, gru, transformer")
    return ActorCritic(
        actor=actor.to(env.device), critic=critic.to(env.device), cost_critic=cost_critic.to(env.device),
        normalizers=norm.to(env.device), recurrent=recurrent, segment_length=segment_length,
    )


__all__ = ["ActorCritic", "make_actor_critic"]
