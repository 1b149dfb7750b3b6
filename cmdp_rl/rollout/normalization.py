"""Running observation normalization and reward/cost scaling, saved with the networks. Observations:
``clip((obs - mean) / std, -c, c)`` by one module in front of the actor and the critics, so evaluation and
a reloaded checkpoint see training's statistics. Reward and cost: each divided by the running std of its
discounted sum before GAE (Engstrom et al. 2020, "Implementation Matters in Deep Policy Gradients"), one
statistic per cost; logged returns, costs and ``J_c <= d`` stay in the env's units.

torchrl's ``RunningMeanStd``, not its ``VecNorm`` transform: that acts on an ``EnvBase`` every env step and
would be saved apart from the networks. Statistics change only in :meth:`Normalizers.scale_batch` (before
the update) and :meth:`Normalizers.update_observation_stats` (after it, so the first PPO ratio is exactly 1).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Optional

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs.transforms import RunningMeanStd

from cmdp_rl.config.run_config import NormalizeConfig
from cmdp_rl.rollout import keys

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig

_EPS = 1e-8


class ObservationNormalizer(nn.Module):
    """``clip((obs - mean) / std, -clip, clip)`` with running statistics that change only in :meth:`update`."""

    def __init__(self, obs_dim: int, clip: float = 10.0) -> None:
        super().__init__()
        self.stats = RunningMeanStd((obs_dim,))
        self.clip = clip

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.stats.normalize(obs).clamp(-self.clip, self.clip)

    @torch.no_grad()
    def update(self, obs: torch.Tensor) -> None:
        self.stats.update(obs.reshape(-1, obs.shape[-1]))


class ReturnScaler(nn.Module):
    """Scales a signal by ``1 / std`` of its running discounted sum per env (reset at episode ends), per channel."""

    def __init__(self, num_envs: int, gamma: float, channels: int = 1) -> None:
        super().__init__()
        self.gamma = gamma
        self.stats = RunningMeanStd(() if channels == 1 else (channels,))
        self.register_buffer("running_return", torch.zeros(num_envs, channels))

    @torch.no_grad()
    def update(self, signal: torch.Tensor, done: torch.Tensor) -> None:
        """``signal``: ``[num_envs, T, channels]``, ``done``: ``[num_envs, T, 1]``, in time order."""
        ret = self.running_return
        sums = []
        for t in range(signal.shape[1]):
            ret = self.gamma * ret + signal[:, t]
            sums.append(ret)
            ret = ret.masked_fill(done[:, t], 0.0)
        self.running_return.copy_(ret)
        self.stats.update(torch.stack(sums, 1))

    def scale(self, signal: torch.Tensor) -> torch.Tensor:
        return signal / (self.stats.var + _EPS).sqrt()


Scaler = Optional[ReturnScaler]


class Normalizers(nn.Module):
    """The normalizers a run uses, each ``None`` when off; ``make_agent`` places ``obs`` in the networks."""

    def __init__(self, obs: ObservationNormalizer | None = None, reward: Scaler = None, cost: Scaler = None) -> None:
        super().__init__()
        self.obs, self.reward, self.cost = obs, reward, cost

    @classmethod
    def from_config(
        cls, cfg: NormalizeConfig, obs_dim: int, num_envs: int, gamma: float, cost_gamma: float, num_costs: int = 1
    ) -> Normalizers:
        return cls(
            ObservationNormalizer(obs_dim, cfg.obs_clip) if cfg.obs else None,
            ReturnScaler(num_envs, gamma) if cfg.reward else None,
            ReturnScaler(num_envs, cost_gamma, num_costs) if cfg.cost else None,
        )

    def scale_batch(self, batch: TensorDictBase) -> None:
        """Before the update: take in the batch's rewards/costs, then scale them in place."""
        done = batch.get((keys.NEXT, keys.DONE))
        for scaler, key in ((self.reward, keys.REWARD), (self.cost, keys.COST)):
            if scaler is not None:
                x = batch.get((keys.NEXT, key))
                scaler.update(x, done)
                batch.set((keys.NEXT, key), scaler.scale(x))

    def update_observation_stats(self, batch: TensorDictBase) -> None:
        """After the update: take in the observations the batch's actions were chosen on."""
        if self.obs is not None:
            self.obs.update(batch.get(keys.OBS))


def make_normalizers(cfg: RunConfig, env: Any) -> Normalizers:
    """The normalizers ``cfg.normalize`` asks for, with the algorithm's discounts, for ``env`` (an ``envs.VecEnv``:
    its ``obs_dim``, ``num_envs`` and ``num_costs``)."""
    return Normalizers.from_config(
        cfg.normalize, env.obs_dim, env.num_envs, cfg.algo.gamma, cfg.algo.cost_gamma, getattr(env, "num_costs", 1)
    )
