"""Transformer policy (``policy=transformer``): causal self-attention over the last K steps.

Each step is a token ``(observation, previous action, previous cost)``; the policy and both critics
attend over the window of the last ``K = policy.window`` tokens of the current episode, this step's
included, with causal self-attention (Vaswani et al., 2017, "Attention Is All You Need", sec. 3.2;
the decoder's mask, sec. 3.2.3) and positions within the window, learned or sinusoidal (sec. 3.5).
Steps before the episode's start are masked out. Parisotto et al. (2020, "Stabilizing
Transformers for Reinforcement Learning") use attention over past steps as a POMDP memory; this
is the plain, windowed form.

Why written here: torchrl 0.14 has no online transformer policy (no GTrXL; see the stack notes),
so it is built on ``torch.nn.TransformerEncoder``.

The window is policy state carried by the collector like a recurrent state: the root holds the
raw tokens of the K - 1 steps before this one (``keys.HISTORY``, oldest first) and which belong to
the current episode (``keys.HISTORY_MASK``); :class:`HistoryWindow` appends this step's token and
returns the shifted history, which the agent writes under ``"next"``. Because each step of a batch carries its own window,
the networks are stateless functions of a step's entries: training uses ordinary shuffled
minibatches of steps, and the output equals a pass over the explicit window of the trajectory
(``tests/test_memory_policies.py``). Tokens are stored raw; observation normalization is applied
when they are read, so a stored window always meets the current statistics.
"""

from __future__ import annotations

import math
from dataclasses import field
from typing import TYPE_CHECKING, Annotated, Literal, Mapping

import torch
from torch import nn
from torch.nn.attention import SDPBackend, sdpa_kernel

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import Bool, Field, PositiveInt, options, require
from cmdp_rl.policies.agent import Actor, Agent, Body, Critic, critic_outputs
from cmdp_rl.policies.distributions import action_outputs, make_action_head
from cmdp_rl.policies.inputs import InputEncoder, input_keys
from cmdp_rl.policies.mlp import Activation, LogStd, mlp
from cmdp_rl.policies.recurrent import HeadSizes
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.normalization import Normalizers

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig
    from cmdp_rl.envs import VecEnv


@options
class TransformerPolicyConfig:
    """``policy=transformer``: causal self-attention over the last ``window`` steps."""

    name: str = "transformer"
    window: Annotated[int, Field(ge=1, description="a positive integer (steps attended to)")] = (
        16  # K, this step included
    )
    layers: PositiveInt = 1
    heads: PositiveInt = 2
    width: PositiveInt = 32  # model width d (divisible by heads)
    feedforward: PositiveInt = 64  # hidden width of each layer's feed-forward block
    positions: Literal["learned", "sinusoidal"] = "learned"
    head_sizes: HeadSizes = field(default_factory=lambda: [64])
    activation: Activation = "tanh"
    init_log_std: LogStd = -0.5
    include_prev_action: Bool = True
    include_prev_cost: Bool = True

    def check(self, run: RunConfig) -> None:
        require(
            self.width % self.heads == 0,
            "policy.width",
            f"a positive multiple of policy.heads={self.heads}",
            self.width,
        )


class HistoryWindow(nn.Module):
    """``(obs, [prev action], [prev cost], history, history mask, is_init)`` -> this step's window
    of K tokens and its mask, and the next step's history (the window's last K - 1 tokens).

    At an episode's first step (``is_init``) the history is ignored: only the current token is valid.
    """

    def __init__(self, window: int, token_dim: int) -> None:
        super().__init__()
        self.window = window
        self.token_dim = token_dim

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        *parts, history, history_mask, is_init = inputs
        token = torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]
        valid = history_mask & ~is_init  # is_init: [..., 1] broadcasts over the K - 1 steps
        window = torch.cat([history, token.unsqueeze(-2)], dim=-2)
        mask = torch.cat([valid, torch.ones_like(is_init)], dim=-1)
        return window, mask, window[..., 1:, :], mask[..., 1:]


def sinusoidal_positions(length: int, width: int) -> torch.Tensor:
    """Vaswani et al. (2017), sec. 3.5: ``PE[p, 2i] = sin(p / 10000^(2i/d))``, ``PE[p, 2i+1] = cos(...)``."""
    pos = torch.arange(length, dtype=torch.float32).unsqueeze(1)
    freq = torch.exp(torch.arange(0, width, 2, dtype=torch.float32) * (-math.log(10000.0) / width))
    pe = torch.zeros(length, width)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq[: width // 2])
    return pe


class WindowTransformer(nn.Module):
    """Embeds a window of raw tokens, runs causal self-attention, returns the last position's
    features ``[..., width]``: pre-norm ``nn.TransformerEncoderLayer``s and a final LayerNorm.

    Attention mask: position i sees positions j <= i of the current episode, and always itself (a
    query with no key would give NaN, which masked weights of 0 would still carry into valid
    positions). Padded positions are therefore never seen by valid ones.

    Only the last position's output is used, so the last layer is evaluated for that query alone
    (:meth:`_last_query`: the layer's own submodules, its arithmetic for one row; equal to the full
    layer's last row, ``tests/test_memory_policies.py``). With one layer this skips the
    attention output, feed-forward block and norms of K - 1 positions: about 3 times faster on CPU
    at K = 16 (measured), the transformer being the slowest head to train.
    """

    def __init__(self, cfg: TransformerPolicyConfig, encoder: InputEncoder, obs_dim: int) -> None:
        super().__init__()
        self.encoder = encoder
        self.obs_dim = obs_dim
        self.heads = cfg.heads
        self.embed = nn.Linear(encoder.out_dim, cfg.width)
        if cfg.positions == "learned":
            self.positions = nn.Parameter(torch.randn(cfg.window, cfg.width) * 0.02)
        else:
            self.register_buffer("positions", sinusoidal_positions(cfg.window, cfg.width))

        def layer() -> nn.TransformerEncoderLayer:
            return nn.TransformerEncoderLayer(
                cfg.width,
                cfg.heads,
                dim_feedforward=cfg.feedforward,
                dropout=0.0,
                batch_first=True,
                norm_first=True,
            )

        self.context = nn.ModuleList(layer() for _ in range(cfg.layers - 1))
        self.last = layer()
        self.norm = nn.LayerNorm(cfg.width)
        self.register_buffer("causal", torch.ones(cfg.window, cfg.window, dtype=torch.bool).tril(), persistent=False)
        self.register_buffer("eye", torch.eye(cfg.window, dtype=torch.bool), persistent=False)

    def _split(self, tokens: torch.Tensor) -> torch.Tensor:
        """Raw tokens -> encoded inputs (normalized observation, action in box units, cost)."""
        obs, prev = tokens[..., : self.obs_dim], tokens[..., self.obs_dim :]
        sizes = []
        if self.encoder.include_prev_action:
            sizes.append(prev.shape[-1] - (self.encoder.num_costs if self.encoder.include_prev_cost else 0))
        if self.encoder.include_prev_cost:
            sizes.append(self.encoder.num_costs)
        return self.encoder(obs, *prev.split(sizes, dim=-1)) if sizes else self.encoder(obs)

    def _last_query(self, x: torch.Tensor, key_blocked: torch.Tensor) -> torch.Tensor:
        """``self.last`` (pre-norm: ``x + SA(LN1(x))``, then ``+ FF(LN2(.))``) for the last query only."""
        layer = self.last
        h = layer.norm1(x)
        attn = layer.self_attn(h[:, -1:], h, h, key_padding_mask=key_blocked, need_weights=False)[0][:, 0]
        y = x[:, -1] + attn
        return y + layer.linear2(layer.activation(layer.linear1(layer.norm2(y))))

    def forward(self, window: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        # torch's math attention kernel: its second derivatives exist (CPO's Fisher-vector products
        # need them; the fused CPU kernel has none), and at these sizes it was as fast (measured).
        with sdpa_kernel(SDPBackend.MATH):
            return self._forward(window, mask)

    def _forward(self, window: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        lead = window.shape[:-2]
        K = window.shape[-2]
        m = mask.reshape(-1, K)
        x = self.embed(self._split(window.reshape(-1, K, window.shape[-1]))) + self.positions
        if len(self.context):
            allowed = (self.causal & m.unsqueeze(-2)) | self.eye  # [B, K (query), K (key)]
            blocked = (~allowed).repeat_interleave(self.heads, dim=0)
            for layer in self.context:
                x = layer(x, src_mask=blocked)
        # The last query sees every valid step (causal: all are at or before it).
        return self.norm(self._last_query(x, ~m)).reshape(*lead, -1)


class _Trunk(nn.Module):
    """transformer features -> head MLP."""

    def __init__(self, body: WindowTransformer, head: nn.Module) -> None:
        super().__init__()
        self.body = body
        self.head = head

    def forward(self, window: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.head(self.body(window, mask))


class TransformerBody(Body):
    """The step's window (:class:`HistoryWindow`, from the carried history) and its mask: the
    features the transformer (the output network after it) reads. Stateless as a function of a
    step's entries (the window travels with its step), so training uses shuffled single steps;
    acting also returns the next step's history."""

    def __init__(self, cfg: TransformerPolicyConfig, token_dim: int) -> None:
        super().__init__()
        self.inputs = input_keys(cfg.include_prev_action, cfg.include_prev_cost)
        self.in_keys = [*self.inputs, keys.HISTORY, keys.HISTORY_MASK, keys.IS_INIT]
        self.state_keys = (keys.HISTORY, keys.HISTORY_MASK)
        self.window = HistoryWindow(cfg.window, token_dim)

    def forward(self, d: Mapping) -> tuple[torch.Tensor, torch.Tensor]:
        window, mask, _, _ = self.window(*(d[k] for k in self.in_keys))
        return window, mask

    def step(self, d: Mapping) -> tuple[tuple[torch.Tensor, torch.Tensor], dict]:
        window, mask, history, history_mask = self.window(*(d[k] for k in self.in_keys))
        return (window, mask), {keys.HISTORY: history, keys.HISTORY_MASK: history_mask}

    def initial_state(self, num_envs: int, device: torch.device) -> dict:
        """An empty history: no token of the window belongs to the episode yet."""
        K, dim = self.window.window, self.window.token_dim
        return {
            keys.HISTORY: torch.zeros(num_envs, K - 1, dim, device=device),
            keys.HISTORY_MASK: torch.zeros(num_envs, K - 1, dtype=torch.bool, device=device),
        }


def make_transformer_agent(cfg: TransformerPolicyConfig, env: VecEnv, normalizers: Normalizers) -> Agent:
    """Actor and critics: a transformer each (then an MLP), over the same carried window (the actor
    carries it)."""

    def network(out_dim: int, out_gain: float) -> _Trunk:
        return _Trunk(
            WindowTransformer(cfg, InputEncoder.of(cfg, env, normalizers.obs), env.obs_dim),
            mlp(cfg.width, cfg.head_sizes, out_dim, cfg.activation, out_gain=out_gain),
        )

    token_dim = InputEncoder.of(
        cfg, env, normalizers.obs
    ).in_dim  # raw tokens: a discrete action is stored as its index
    head = make_action_head(env.action_space, network(action_outputs(env.action_space), 0.01), cfg.init_log_std)
    actor = Actor(TransformerBody(cfg, token_dim), head)
    critics = {
        signal: Critic(TransformerBody(cfg, token_dim), network(critic_outputs(signal, env), 1.0))
        for signal in ("reward", "cost")
    }
    return Agent(actor, critics, normalizers, cost_names=env.cost_names)


register("policy", "transformer", TransformerPolicyConfig, make_transformer_agent)
