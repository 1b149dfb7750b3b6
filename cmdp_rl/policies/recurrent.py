"""LSTM and GRU policies (``policy=lstm|gru``): memory in the actor and in both critics.

Under partial observation a policy on ``o_t`` alone is suboptimal wherever states share
observations; it must act on a statistic of the history, ideally the belief
``b_t(s) = P(s_t = s | o_0..o_t, a_0..a_{t-1})`` (Kaelbling, Littman, Cassandra, 1998, "Planning and
Acting in Partially Observable Stochastic Domains", sec. 3). A recurrent network learns such a
statistic in its state (Wierstra et al., 2007, "Solving Deep Memory POMDPs with Recurrent Policy
Gradients"; Hausknecht & Stone, 2015, "Deep Recurrent Q-Learning for POMDPs").

The actor and each critic is a :class:`RecurrentBody`, ``inputs -> torchrl LSTMModule/GRUModule ->
MLP head``, with its own recurrent state (``keys.ACTOR_HIDDEN`` ... ``keys.COST_CRITIC_CELL``):

- Acting (the collector, evaluation): one step. The body reads the state at the root and returns
  the next one, which the agent writes under ``"next"``; the collector carries it to the next step
  and resets it to the initial state (zeros) where an episode ended; ``is_init`` (torchrl's
  InitTracker convention) also makes the body zero the state it reads.
- Training: recurrent mode on ``[B, L]`` segments of the batch (see :class:`RecurrentBody`).

The critics are stepped in the rollout too (``Agent.act``) so that their state at every step is in
the batch as well: a rollout of 32 steps starts mid-episode, and a critic can only be re-run on a
segment from a stored state (see ``Agent.rollout_values``).
"""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, Annotated, Literal, Mapping

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.modules import GRUModule, LSTMModule, set_recurrent_mode

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import Bool, Field, NonNegativeInt, PositiveInt, options, require
from cmdp_rl.policies.agent import Actor, Agent, Body, Critic, critic_outputs
from cmdp_rl.policies.distributions import action_outputs, make_action_head
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
    # Training segments: steps per segment, a divisor of rollout_steps; 0 or >= rollout_steps:
    # whole rollout rows.
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


STATE_KEYS: dict[str, dict[str, tuple[str, ...]]] = {
    "lstm": {
        "actor": (keys.ACTOR_HIDDEN, keys.ACTOR_CELL),
        "critic": (keys.CRITIC_HIDDEN, keys.CRITIC_CELL),
        "cost_critic": (keys.COST_CRITIC_HIDDEN, keys.COST_CRITIC_CELL),
    },
    "gru": {
        "actor": (keys.ACTOR_HIDDEN,),
        "critic": (keys.CRITIC_HIDDEN,),
        "cost_critic": (keys.COST_CRITIC_HIDDEN,),
    },
}


def memory_module(cfg: RecurrentPolicyConfig, input_size: int, state: tuple[str, ...]) -> LSTMModule | GRUModule:
    """torchrl's recurrent module from ``keys.NET_INPUT`` to ``keys.FEATURES``, its state under ``state``."""
    out_state = [(keys.NEXT, k) for k in state]
    common = dict(input_size=input_size, hidden_size=cfg.hidden_size, num_layers=cfg.num_layers)
    if cfg.name == "lstm":
        return LSTMModule(
            **common, in_keys=[keys.NET_INPUT, *state, keys.IS_INIT], out_keys=[keys.FEATURES, *out_state]
        )
    return GRUModule(**common, in_keys=[keys.NET_INPUT, *state, keys.IS_INIT], out_keys=[keys.FEATURES, *out_state])


class RecurrentBody(Body):
    """inputs -> encoder -> torchrl LSTM/GRU module, with a recurrent state of its own (the MLP
    after it is the network's output network).

    Acting steps the module's ``nn.LSTM``/``nn.GRU`` once on ``[N, ...]`` entries (the state read is
    zeroed where ``is_init``). Training runs torchrl's module in recurrent mode
    (``set_recurrent_mode``) on ``[B, L]`` segments, through a TensorDict: the one place torchrl
    needs one. It starts each segment from the state stored at its first step and restarts from
    that step's stored (zero) state wherever ``is_init`` marks an episode start inside it.
    """

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
    states = STATE_KEYS[cfg.name]

    def body(net: str) -> RecurrentBody:
        return RecurrentBody(cfg, InputEncoder.of(cfg, env, normalizers.obs), states[net])

    def head_mlp(out_dim: int, out_gain: float = 1.0) -> nn.Sequential:
        return mlp(cfg.hidden_size, cfg.head_sizes, out_dim, cfg.activation, out_gain=out_gain)

    # Each network's output MLP is built before its memory: the parameters' init order.
    net = head_mlp(action_outputs(env.action_space), 0.01)
    actor = Actor(body("actor"), make_action_head(env.action_space, net, cfg.init_log_std))
    critics = {}
    for signal, name in (("reward", "critic"), ("cost", "cost_critic")):
        net = head_mlp(critic_outputs(signal, env))
        critics[signal] = Critic(body(name), net)
    return Agent(actor, critics, normalizers, segment_length=cfg.segment_length, cost_names=env.cost_names)


register("policy", "lstm", RecurrentPolicyConfig, make_recurrent_agent)
register("policy", "gru", RecurrentPolicyConfig, make_recurrent_agent)
