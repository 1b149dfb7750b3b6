"""Transformer policy (``policy=transformer``): causal self-attention (Vaswani et al., 2017, sec. 3.2; learned
or sinusoidal positions, sec. 3.5) over the last ``K = policy.window`` tokens ``(observation, previous action,
previous cost)`` of the episode, a POMDP memory as in Parisotto et al. (2020). torchrl has no online
transformer policy. The window is state the collector carries (``keys.HISTORY``, ``keys.HISTORY_MASK``), so
training uses shuffled single steps; tokens are stored raw and normalized when read."""

from __future__ import annotations

import math
from dataclasses import field
from typing import TYPE_CHECKING, Annotated, Literal, Mapping

import torch
from torch import nn
from torch.nn.attention import SDPBackend, sdpa_kernel

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import Bool, Field, PositiveInt, options, require
from cmdp_rl.policies.agent import Agent, Body, actor_and_critics
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
    window: Annotated[int, Field(ge=1, description="a positive integer (steps attended to)")] = 16
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


def sinusoidal_positions(length: int, width: int) -> torch.Tensor:
    """Vaswani et al. (2017), sec. 3.5: ``PE[p, 2i] = sin(p / 10000^(2i/d))``, ``PE[p, 2i+1] = cos(...)``."""
    pos = torch.arange(length, dtype=torch.float32).unsqueeze(1)
    freq = torch.exp(torch.arange(0, width, 2, dtype=torch.float32) * (-math.log(10000.0) / width))
    pe = torch.zeros(length, width)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq[: width // 2])
    return pe


class WindowTransformer(nn.Module):
    """A window of raw tokens -> embedding, causal self-attention (pre-norm layers, a final LayerNorm) -> the last
    position's features ``[..., width]``. Position i sees j <= i of the episode and always itself (a query with no
    key gives NaN); the last layer runs for the last query alone (:meth:`_last_query`), the only one used."""

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
                cfg.width, cfg.heads, dim_feedforward=cfg.feedforward, dropout=0.0, batch_first=True, norm_first=True
            )

        self.context = nn.ModuleList(layer() for _ in range(cfg.layers - 1))
        self.last = layer()
        self.norm = nn.LayerNorm(cfg.width)
        self.register_buffer("causal", torch.ones(cfg.window, cfg.window, dtype=torch.bool).tril(), persistent=False)
        self.register_buffer("eye", torch.eye(cfg.window, dtype=torch.bool), persistent=False)

    def _split(self, tokens: torch.Tensor) -> torch.Tensor:
        """Raw tokens -> encoded inputs (normalized observation, action in box units, cost)."""
        costs = self.encoder.num_costs if self.encoder.include_prev_cost else 0
        sizes = [self.obs_dim, tokens.shape[-1] - self.obs_dim - costs, costs]  # the parts not read are empty
        return self.encoder(*(part for part in tokens.split(sizes, dim=-1) if part.shape[-1]))

    def _last_query(self, x: torch.Tensor, key_blocked: torch.Tensor) -> torch.Tensor:
        """``self.last`` (pre-norm: ``x + SA(LN1(x))``, then ``+ FF(LN2(.))``) for the last query only."""
        layer = self.last
        h = layer.norm1(x)
        attn = layer.self_attn(h[:, -1:], h, h, key_padding_mask=key_blocked, need_weights=False)[0][:, 0]
        y = x[:, -1] + attn
        return y + layer.linear2(layer.activation(layer.linear1(layer.norm2(y))))

    def forward(self, window: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        # torch's math kernel: its second derivatives exist (CPO's Fisher-vector products), the fused one's not.
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
    """``(obs, [prev action], [prev cost], history, history mask, is_init)`` -> the step's window of K tokens and its
    mask; acting also returns the next history (the last K - 1). Where ``is_init`` the history is ignored."""

    def __init__(self, cfg: TransformerPolicyConfig, token_dim: int) -> None:
        super().__init__()
        inputs = input_keys(cfg.include_prev_action, cfg.include_prev_cost)
        self.in_keys = [*inputs, keys.HISTORY, keys.HISTORY_MASK, keys.IS_INIT]
        self.state_keys = (keys.HISTORY, keys.HISTORY_MASK)
        self.window, self.token_dim = cfg.window, token_dim

    def forward(self, d: Mapping) -> tuple[torch.Tensor, torch.Tensor]:
        return self.step(d)[0]

    def step(self, d: Mapping) -> tuple[tuple[torch.Tensor, torch.Tensor], dict]:
        *parts, history, history_mask, is_init = (d[k] for k in self.in_keys)
        token = torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]
        valid = history_mask & ~is_init  # is_init: [..., 1] broadcasts over the K - 1 steps
        window = torch.cat([history, token.unsqueeze(-2)], dim=-2)
        mask = torch.cat([valid, torch.ones_like(is_init)], dim=-1)
        return (window, mask), {keys.HISTORY: window[..., 1:, :], keys.HISTORY_MASK: mask[..., 1:]}

    def initial_state(self, num_envs: int, device: torch.device) -> dict:
        """An empty history: no token of the window belongs to the episode yet."""
        return {
            keys.HISTORY: torch.zeros(num_envs, self.window - 1, self.token_dim, device=device),
            keys.HISTORY_MASK: torch.zeros(num_envs, self.window - 1, dtype=torch.bool, device=device),
        }


def make_transformer_agent(cfg: TransformerPolicyConfig, env: VecEnv, normalizers: Normalizers) -> Agent:
    """Actor and critics: a transformer each (then an MLP), over the same carried window."""
    token_dim = InputEncoder.of(cfg, env, normalizers.obs).in_dim  # raw tokens: a discrete action as its index

    def network(role: str, out_dim: int, out_gain: float) -> tuple[TransformerBody, _Trunk]:
        transformer = WindowTransformer(cfg, InputEncoder.of(cfg, env, normalizers.obs), env.obs_dim)
        trunk = _Trunk(transformer, mlp(cfg.width, cfg.head_sizes, out_dim, cfg.activation, out_gain))
        return TransformerBody(cfg, token_dim), trunk

    return actor_and_critics(env, normalizers, cfg.init_log_std, network)


register("policy", "transformer", TransformerPolicyConfig, make_transformer_agent)
