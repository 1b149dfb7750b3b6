"""The off-policy agent (docs/off_policy.md): :func:`to_off_policy` turns ``policy=mlp``'s agent into SAC's
:class:`TanhGaussianHead` (Haarnoja et al. 2018, appendix C) or TD3's :class:`DeterministicHead` (exploring
through :class:`ClippedNormal`) and Q-critics on :class:`QBody`, keeping the actor's body and the MLP's shape."""

from __future__ import annotations

from typing import Mapping

import torch
from torch import distributions as D
from torch import nn
from torchrl.modules import IndependentNormal, TanhNormal

from cmdp_rl.config.validation import ConfigError
from cmdp_rl.policies.agent import Actor, Agent, Body, Critic
from cmdp_rl.policies.distributions import GaussianHead
from cmdp_rl.policies.mlp import _ACTIVATIONS, MLPBody, mlp
from cmdp_rl.rollout import keys

Q_REWARD = ("q_reward_0", "q_reward_1")  # the twin reward Q-critics (clipped double Q)
Q_COST = "q_cost"  # the cost Q-critic, one output per constraint
LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # the usual clamp on the pre-tanh log-std (SAC's reference code)


class TanhGaussianHead(nn.Module):
    """``net(features)`` -> ``(mu, sigma)`` of the pre-tanh Gaussian (torchrl's ``TanhNormal`` on the box)."""

    param_keys = (keys.LOC, keys.SCALE)

    def __init__(self, net: nn.Module, low: torch.Tensor, high: torch.Tensor) -> None:
        super().__init__()
        self.net = net
        self.register_buffer("low", low.clone())
        self.register_buffer("high", high.clone())
        self.register_buffer("half_width", (high - low) / 2)

    def forward(self, *features: torch.Tensor) -> dict[str, torch.Tensor]:
        mu, log_std = self.net(*features).chunk(2, dim=-1)
        return {keys.LOC: mu, keys.SCALE: log_std.clamp(LOG_STD_MIN, LOG_STD_MAX).exp()}

    def dist(self, params: dict[str, torch.Tensor]) -> D.Distribution:
        return TanhNormal(params[keys.LOC], params[keys.SCALE], low=self.low, high=self.high)


class ClippedNormal(IndependentNormal):
    """TD3's behaviour policy: the action plus Gaussian noise, clipped to the box (``log_prob``: unclipped)."""

    def __init__(self, loc: torch.Tensor, scale: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> None:
        super().__init__(loc, scale)
        self.low, self.high = low, high

    def rsample(self, sample_shape: torch.Size = torch.Size()) -> torch.Tensor:
        return torch.maximum(torch.minimum(super().rsample(sample_shape), self.high), self.low)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        return self.mean


class DeterministicHead(nn.Module):
    """``net(features)`` -> the action ``center + half_width * tanh(.)`` and the noise's std ``noise * half_width``."""

    param_keys = (keys.LOC, keys.SCALE)

    def __init__(self, net: nn.Module, low: torch.Tensor, high: torch.Tensor, noise: float) -> None:
        super().__init__()
        self.net = net
        self.noise = noise
        self.register_buffer("low", low.clone())
        self.register_buffer("high", high.clone())
        self.register_buffer("center", (high + low) / 2)
        self.register_buffer("half_width", (high - low) / 2)

    def forward(self, *features: torch.Tensor) -> dict[str, torch.Tensor]:
        loc = self.center + self.half_width * torch.tanh(self.net(*features))
        # A zero std would make the Normal invalid; the deterministic action ignores it anyway.
        scale = (self.half_width * max(self.noise, 1e-6)).expand_as(loc)
        return {keys.LOC: loc, keys.SCALE: scale}

    def dist(self, params: dict[str, torch.Tensor]) -> D.Distribution:
        return ClippedNormal(params[keys.LOC], params[keys.SCALE], self.low, self.high)


class QBody(Body):
    """The Q-critic's inputs: the actor body's observation and the action scaled to [-1, 1]."""

    def __init__(self, obs_body: MLPBody, low: torch.Tensor, high: torch.Tensor) -> None:
        super().__init__()
        self.obs_body = obs_body
        self.in_keys = [*obs_body.in_keys, keys.ACTION]
        self.register_buffer("center", (high + low) / 2)
        self.register_buffer("half_width", (high - low) / 2)

    def forward(self, d: Mapping) -> tuple[torch.Tensor]:
        (obs,) = self.obs_body(d)
        return (torch.cat([obs, (d[keys.ACTION] - self.center) / self.half_width], dim=-1),)


def _mlp_shape(net: nn.Sequential) -> tuple[int, list[int], str]:
    """(input size, hidden widths, activation) of a network :func:`mlp` built."""
    linear = [m for m in net if isinstance(m, nn.Linear)]
    act = next(name for name, cls in _ACTIVATIONS.items() if any(isinstance(m, cls) for m in net))
    return linear[0].in_features, [m.out_features for m in linear[:-1]], act


def check_off_policy_agent(agent: Agent, algo: str) -> None:
    """One-line config errors for the agents an off-policy algorithm cannot train."""
    body = agent.actor.body
    if not isinstance(body, MLPBody) or agent.recurrent:
        raise ConfigError(
            f"policy.name must be mlp for algo={algo} (a replay buffer of single steps; "
            f"recurrent and transformer policies are not supported), got {type(body).__name__}"
        )
    if keys.PREV_ACTION in body.in_keys or keys.PREV_COST in body.in_keys:
        raise ConfigError(f"policy.include_prev_action and policy.include_prev_cost must be false for algo={algo}")
    if not isinstance(agent.actor.head, GaussianHead):
        raise ConfigError(
            f"algo must be an on-policy algorithm (ppo, ppo_lag, ...) for a discrete or hybrid action space: "
            f"{algo} needs a Box action space"
        )
    if not torch.isfinite(agent.actor.head.half_width).all():
        raise ConfigError(f"algo={algo} needs a Box action space with finite bounds (its actions are squashed into it)")


def check_shaped(agent: Agent, algo: str) -> None:
    """An off-policy algorithm trains the agent ``make_agent(..., algo=...)`` shapes, not the policy's own."""
    if Q_COST not in agent.critics:
        raise ValueError(f"algo={algo}: build its agent with make_agent(..., algo=<its options>)")


def to_off_policy(agent: Agent, actor: str, td3_noise: float = 0.1) -> Agent:
    """Give ``agent`` (an MLP agent, :func:`check_off_policy_agent`) the off-policy actor head (``actor``:
    ``"tanh_gaussian"`` or ``"deterministic"``) and the Q-critics, in place; returns it."""
    head = agent.actor.head
    low, high = head.center - head.half_width, head.center + head.half_width
    in_dim, hidden, activation = _mlp_shape(head.net)  # the policy's MLP: the same shape again
    act_dim = low.numel()
    device = head.center.device
    if actor == "tanh_gaussian":
        new_head = TanhGaussianHead(mlp(in_dim, hidden, 2 * act_dim, activation, out_gain=0.01), low, high)
    else:
        new_head = DeterministicHead(mlp(in_dim, hidden, act_dim, activation, out_gain=0.01), low, high, td3_noise)
    body = agent.actor.body
    agent.actor = Actor(body, new_head).to(device)

    def q(outputs: int) -> Critic:
        return Critic(QBody(body, low, high), mlp(in_dim + act_dim, hidden, outputs, activation))

    critics = {name: q(1) for name in Q_REWARD}
    critics[Q_COST] = q(agent.num_costs)
    agent.critics = nn.ModuleDict(critics).to(device)
    # ReLU in place: no fresh [B, width] tensor per layer (the Linear before it keeps nothing of its output).
    for m in (*agent.actor.modules(), *agent.critics.modules()):
        if isinstance(m, nn.ReLU):
            m.inplace = True
    return agent
