"""``policy=mlp``: the memoryless policy; actor and critics are MLPs on the step's own entries."""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, Annotated, Literal, Mapping

import torch
from torch import nn

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import Bool, ConfigError, Field, finite, options
from cmdp_rl.policies.agent import Agent, Body, actor_and_critics
from cmdp_rl.policies.inputs import InputEncoder, input_keys
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.normalization import Normalizers

if TYPE_CHECKING:
    from cmdp_rl.envs import VecEnv

Activation = Literal["tanh", "relu", "elu"]
LogStd = Annotated[float, finite()]


@options
class PolicyConfig:
    """``policy=mlp``. ``include_prev_*``: also read the previous action and cost (zero at an episode's start)."""

    name: str = "mlp"
    hidden_sizes: Annotated[
        list[Annotated[int, Field(ge=1)]], Field(min_length=1, description="a non-empty list of positive integers")
    ] = field(default_factory=lambda: [64, 64])
    activation: Activation = "tanh"
    init_log_std: LogStd = -0.5
    include_prev_action: Bool = False
    include_prev_cost: Bool = False


class _SigmoidTanh(torch.autograd.Function):
    """tanh(x) = 2 sigmoid(2x) - 1, with tanh's own backward ``g (1 - y^2)``."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        y = torch.sigmoid(x * 2).mul_(2).sub_(1)
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (y,) = ctx.saved_tensors
        return torch.ops.aten.tanh_backward(grad, y)


class Tanh(nn.Module):
    """tanh as ``2 sigmoid(2x) - 1`` on large CPU inputs: several times faster than torch's CPU kernel, tanh having been
    training's largest cost (docs/throughput.md); equal within float32 rounding, with tanh's own gradient. Small
    inputs (one call beats three plus the autograd function there) and CUDA keep torch.tanh."""

    MIN_NUMEL = 1 << 15  # about the break-even

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.device.type != "cpu" or x.numel() < self.MIN_NUMEL:
            return torch.tanh(x)
        if torch.is_grad_enabled() and x.requires_grad:
            return _SigmoidTanh.apply(x)
        return torch.sigmoid(x * 2).mul_(2).sub_(1)


_ACTIVATIONS = {"tanh": Tanh, "relu": nn.ReLU, "elu": nn.ELU}


class MLP(nn.Sequential):
    """``nn.Sequential`` calling each layer's ``forward`` directly: ``Module.__call__``'s unused hooks cost a kernel."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self._modules.values():
            x = layer.forward(x)
        return x


def mlp(in_dim: int, hidden: list[int], out_dim: int, activation: str, out_gain: float = 1.0) -> nn.Sequential:
    layers: list[nn.Module] = []
    for h in hidden:
        layers += [nn.Linear(in_dim, h), _ACTIVATIONS[activation]()]
        in_dim = h
    layers.append(nn.Linear(in_dim, out_dim))
    # Orthogonal init as in the PPO implementation-details literature (Huang et al., 2022).
    for m in layers:
        if isinstance(m, nn.Linear):
            nn.init.orthogonal_(m.weight, gain=2**0.5)
            nn.init.zeros_(m.bias)
    nn.init.orthogonal_(layers[-1].weight, gain=out_gain)
    return MLP(*layers)


class MLPBody(Body):
    """The MLP's inputs: the observation (normalized if ``obs_norm``) or ``encoder``'s encoding; no parameters."""

    def __init__(self, obs_norm: nn.Module | None, encoder: InputEncoder | None, take: int | None = None) -> None:
        super().__init__()
        self.take = take  # read only the first `take` inputs (a multi-agent row's own part)
        self.prep = encoder if encoder is not None else obs_norm
        self.in_keys = (
            input_keys(encoder.include_prev_action, encoder.include_prev_cost) if encoder is not None else [keys.OBS]
        )

    def forward(self, d: Mapping) -> tuple[torch.Tensor]:
        inputs = [d[k] for k in self.in_keys]
        x = inputs[0] if self.prep is None else self.prep(*inputs)
        return (x if self.take is None else x[..., : self.take],)


def make_mlp_agent(cfg: PolicyConfig, env: VecEnv, normalizers: Normalizers) -> Agent:
    """Actor and critics, each an MLP of its own on the same inputs."""
    obs_norm = normalizers.obs
    encoder = InputEncoder.of(cfg, env, obs_norm) if cfg.include_prev_action or cfg.include_prev_cost else None
    in_dim = env.obs_dim if encoder is None else encoder.out_dim
    # A multi-agent env (envs/multi_agent.py): the shared actor reads its agent's own observation
    # and id, the critics every agent's (MAPPO's decentralised actor and centralised critic).
    local = getattr(env, "actor_obs_dim", None)
    if local is not None and encoder is not None:
        raise ConfigError("policy.include_prev_action and policy.include_prev_cost must be false on a multi-agent env")

    def network(role: str, out_dim: int, out_gain: float) -> tuple[MLPBody, nn.Sequential]:
        take = local if role == "actor" else None
        return MLPBody(obs_norm, encoder, take), mlp(
            take or in_dim, cfg.hidden_sizes, out_dim, cfg.activation, out_gain
        )

    return actor_and_critics(env, normalizers, cfg.init_log_std, network)


register("policy", "mlp", PolicyConfig, make_mlp_agent)
