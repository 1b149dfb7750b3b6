"""LSTM and GRU policies (``policy=lstm|gru``): a memory in the actor and in both critics, which learns a
statistic of the history such as the belief (Kaelbling, Littman, Cassandra, 1998; docs/guide/policies.md). The
critics are stepped in the rollout too: a rollout starts mid-episode, and a critic can only be re-run on a
segment from its stored state (``Agent.rollout_values``)."""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, Annotated, Literal, Mapping

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.modules import GRUModule, LSTMModule, set_recurrent_mode

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import Bool, Field, NonNegativeInt, PositiveInt, options, require
from cmdp_rl.policies.agent import Agent, Body, actor_and_critics
from cmdp_rl.policies.inputs import InputEncoder, input_keys
from cmdp_rl.policies.mlp import Activation, LogStd, mlp
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.normalization import Normalizers

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig
    from cmdp_rl.envs import VecEnv

HeadSizes = Annotated[
    list[Annotated[int, Field(ge=1)]], Field(description="a list of positive integers (may be empty)")
]


@options
class RecurrentPolicyConfig:
    """``policy=lstm`` or ``policy=gru``: LSTM or GRU memory in the actor and in both critics."""

    name: Literal["lstm", "gru"] = "lstm"
    hidden_size: PositiveInt = 64  # recurrent units
    num_layers: PositiveInt = 1  # stacked recurrent layers
    head_sizes: HeadSizes = field(default_factory=lambda: [64])  # MLP after the memory ([]: linear)
    activation: Activation = "tanh"
    init_log_std: LogStd = -0.5
    include_prev_action: Bool = True
    include_prev_cost: Bool = True
    # Training segments: steps per segment, a divisor of rollout_steps; 0 or >= rollout_steps: whole rollout rows.
    segment_length: NonNegativeInt = 32

    def check(self, run: RunConfig) -> None:
        L, T = self.segment_length, run.rollout_steps
        require(
            L == 0 or L >= T or T % L == 0,
            "policy.segment_length",
            f"0 or >= rollout_steps (whole rollouts), or a divisor of rollout_steps={T}",
            L,
        )
        segments = run.env.num_envs * (T // L if 0 < L < T else 1)
        for name in ("num_minibatches", "critic_minibatches"):  # PPO family, CPO's critic fit
            if hasattr(run.algo, name):
                require(
                    getattr(run.algo, name) <= segments,
                    f"algo.{name}",
                    f"at most the number of training segments, env.num_envs * rollout_steps / "
                    f"policy.segment_length = {segments} (recurrent policies train on whole segments)",
                    getattr(run.algo, name),
                )


# Each network's state entries: an LSTM's hidden and cell state, a GRU's hidden state alone.
STATE_KEYS = {
    "actor": (keys.ACTOR_HIDDEN, keys.ACTOR_CELL),
    "reward": (keys.CRITIC_HIDDEN, keys.CRITIC_CELL),
    "cost": (keys.COST_CRITIC_HIDDEN, keys.COST_CRITIC_CELL),
}


def memory_module(cfg: RecurrentPolicyConfig, input_size: int, state: tuple[str, ...]) -> LSTMModule | GRUModule:
    """torchrl's recurrent module from ``keys.NET_INPUT`` to ``keys.FEATURES``, its state under ``state``."""
    module = LSTMModule if cfg.name == "lstm" else GRUModule
    return module(
        input_size=input_size,
        hidden_size=cfg.hidden_size,
        num_layers=cfg.num_layers,
        in_keys=[keys.NET_INPUT, *state, keys.IS_INIT],
        out_keys=[keys.FEATURES, *((keys.NEXT, k) for k in state)],
    )


class RecurrentBody(Body):
    """inputs -> encoder -> torchrl LSTM/GRU module, stepped once when acting (state zeroed where ``is_init``), run
    in recurrent mode on ``[B, L]`` segments from their stored state for training."""

    recurrent = True

    def __init__(self, cfg: RecurrentPolicyConfig, encoder: InputEncoder, state: tuple[str, ...]) -> None:
        super().__init__()
        self.encoder = encoder
        self.memory = memory_module(cfg, encoder.out_dim, state)
        self.inputs = input_keys(cfg.include_prev_action, cfg.include_prev_cost)
        self.state_keys = state
        self.in_keys = [*self.inputs, *state, keys.IS_INIT]
        self.state_shape = (cfg.num_layers, cfg.hidden_size)

    def forward(self, d: Mapping) -> tuple[torch.Tensor]:
        return self.forward_with_state(d)[0]

    def forward_with_state(self, d: Mapping) -> tuple[tuple[torch.Tensor], dict]:
        x = self.encoder(*(d[k] for k in self.inputs))
        td = TensorDict(
            {keys.NET_INPUT: x, keys.IS_INIT: d[keys.IS_INIT], **{k: d[k] for k in self.state_keys}},
            batch_size=x.shape[:-1],
        )
        with set_recurrent_mode(True):
            out = self.memory(td)
        return (out.get(keys.FEATURES),), {k: out.get((keys.NEXT, k)) for k in self.state_keys}

    def step(self, d: Mapping) -> tuple[tuple[torch.Tensor], dict]:
        x = self.encoder(*(d[k] for k in self.inputs))
        rnn = self.memory.lstm if isinstance(self.memory, LSTMModule) else self.memory.gru
        fresh = d[keys.IS_INIT].view(-1, 1, 1)
        # torchrl's state layout is [batch, layers, hidden]; nn.LSTM's [layers, batch, hidden].
        states = [
            torch.where(fresh, torch.zeros_like(d[k]), d[k]).transpose(0, 1).contiguous() for k in self.state_keys
        ]
        y, new = rnn(x.unsqueeze(1), tuple(states) if len(states) == 2 else states[0])
        new = new if isinstance(new, tuple) else (new,)
        return (y.squeeze(1),), {k: h.transpose(0, 1) for k, h in zip(self.state_keys, new)}

    def initial_state(self, num_envs: int, device: torch.device) -> dict:
        return {k: torch.zeros(num_envs, *self.state_shape, device=device) for k in self.state_keys}


def make_recurrent_agent(cfg: RecurrentPolicyConfig, env: VecEnv, normalizers: Normalizers) -> Agent:
    """Actor and critics, each with a memory of its own and an MLP after it."""

    def network(role: str, out_dim: int, out_gain: float) -> tuple[RecurrentBody, nn.Sequential]:
        net = mlp(cfg.hidden_size, cfg.head_sizes, out_dim, cfg.activation, out_gain)  # before the memory: init order
        encoder = InputEncoder.of(cfg, env, normalizers.obs)
        return RecurrentBody(cfg, encoder, STATE_KEYS[role][: 2 if cfg.name == "lstm" else 1]), net

    return actor_and_critics(env, normalizers, cfg.init_log_std, network, segment_length=cfg.segment_length)


register("policy", "lstm", RecurrentPolicyConfig, make_recurrent_agent)
register("policy", "gru", RecurrentPolicyConfig, make_recurrent_agent)
