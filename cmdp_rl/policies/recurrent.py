"""LSTM and GRU policies (``policy=lstm|gru``): memory in the actor and in both critics.

Under partial observation a policy on ``o_t`` alone is suboptimal wherever states share
observations; it must act on a statistic of the history, ideally the belief
``b_t(s) = P(s_t = s | o_0..o_t, a_0..a_{t-1})`` (Kaelbling, Littman, Cassandra, 1998, "Planning and
Acting in Partially Observable Stochastic Domains", sec. 3). A recurrent network learns such a
statistic in its state (Wierstra et al., 2007, "Solving Deep Memory POMDPs with Recurrent Policy
Gradients"; Hausknecht & Stone, 2015, "Deep Recurrent Q-Learning for POMDPs").

Each of the three networks is ``inputs -> torchrl LSTMModule/GRUModule -> MLP head`` with its
own recurrent state (``keys.ACTOR_HIDDEN`` ... ``keys.COST_CRITIC_CELL``):

- Acting (the collector, evaluation): step mode. The module reads the state at the root and
  writes the next one under ``"next"``; the collector carries it to the next step and resets it to
  the initial state (zeros, from torchrl's ``make_tensordict_primer``) where an episode ended;
  ``is_init`` (torchrl's InitTracker convention) also makes the module zero the state it reads.
- Training: recurrent mode (``set_recurrent_mode(True)``) on ``[B, L]`` segments of the batch.
  torchrl's module starts each segment from the state stored at its first step and restarts from
  that step's stored (zero) state wherever ``is_init`` marks an episode start inside it.

The critics are stepped in the rollout too (:attr:`ActorCritic.rollout_policy`) so that their
state at every step is in the batch as well: a rollout of 32 steps starts mid-episode, and a
critic can only be re-run on a segment from a stored state (see ``advantages.py``).
"""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, Annotated, Literal

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import GRUModule, LSTMModule

from cmdp_rl import keys
from cmdp_rl.policies.inputs import InputEncoder, input_keys
from cmdp_rl.policies.mlp import Activation, GaussianHead, LogStd, build_agent, gaussian_actor, mlp
from cmdp_rl.registry import register
from cmdp_rl.validation import Bool, Field, NonNegativeInt, PositiveInt, options, require

if TYPE_CHECKING:
    from cmdp_rl.config import RunConfig

HeadSizes = Annotated[list[Annotated[int, Field(ge=1)]], Field(description="a list of positive integers (may be empty)")]


@options
class RecurrentPolicyConfig:
    """``policy=lstm`` or ``policy=gru``: LSTM or GRU memory in the actor and in both critics."""

    name: Literal["lstm", "gru"] = "lstm"
    hidden_size: PositiveInt = 64       # recurrent units
    num_layers: PositiveInt = 1         # stacked recurrent layers
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
        require(L == 0 or L >= T or T % L == 0, "policy.segment_length",
                f"0 or >= rollout_steps (whole rollouts), or a divisor of rollout_steps={T}", L)
        segments = run.env.num_envs * (T // L if 0 < L < T else 1)
        for name in ("num_minibatches", "critic_minibatches"):  # PPO family, CPO's critic fit
            if hasattr(run.algo, name):
                require(getattr(run.algo, name) <= segments, f"algo.{name}",
                        f"at most the number of training segments, env.num_envs * rollout_steps / "
                        f"policy.segment_length = {segments} (recurrent policies train on whole segments)",
                        getattr(run.algo, name))

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
        return LSTMModule(**common, in_keys=[keys.NET_INPUT, *state, keys.IS_INIT], out_keys=[keys.FEATURES, *out_state])
    return GRUModule(**common, in_keys=[keys.NET_INPUT, *state, keys.IS_INIT], out_keys=[keys.FEATURES, *out_state])


def _network(cfg: RecurrentPolicyConfig, encoder: InputEncoder, state: tuple[str, ...], head: nn.Module,
             out_keys: list[str]) -> TensorDictSequential:
    """inputs -> encoder -> memory -> head; writes only ``out_keys`` and the next state."""
    return TensorDictSequential(
        TensorDictModule(encoder, input_keys(cfg.include_prev_action, cfg.include_prev_cost), [keys.NET_INPUT]),
        memory_module(cfg, encoder.out_dim, state),
        TensorDictModule(head, [keys.FEATURES], out_keys),
        selected_out_keys=[*out_keys, *((keys.NEXT, k) for k in state)],
    )


def make_recurrent_networks(
    cfg: RecurrentPolicyConfig, obs_dim: int, low: torch.Tensor, high: torch.Tensor, obs_norm: nn.Module | None
) -> tuple[nn.Module, TensorDictSequential, TensorDictSequential]:
    """(actor, critic, cost critic), each with a memory of its own."""
    states = STATE_KEYS[cfg.name]

    def encoder() -> InputEncoder:
        return InputEncoder(obs_dim, low, high, cfg.include_prev_action, cfg.include_prev_cost, obs_norm)

    def critic(state: tuple[str, ...], out_key: str) -> TensorDictSequential:
        return _network(cfg, encoder(), state, mlp(cfg.hidden_size, cfg.head_sizes, 1, cfg.activation), [out_key])

    head = GaussianHead(mlp(cfg.hidden_size, cfg.head_sizes, low.numel(), cfg.activation, out_gain=0.01),
                        low, high, cfg.init_log_std)
    actor = gaussian_actor(_network(cfg, encoder(), states["actor"], head, [keys.LOC, keys.SCALE]))
    return actor, critic(states["critic"], keys.VALUE), critic(states["cost_critic"], keys.COST_VALUE)


register("policy", "lstm", RecurrentPolicyConfig, build_agent)
register("policy", "gru", RecurrentPolicyConfig, build_agent)
