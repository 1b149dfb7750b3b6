"""Twin critics, twin GAEs: torchrl's GAE for reward and for cost on values the critics wrote beforehand
(one critic pass serves GAE and the logging); a truncated step bootstraps unless ``terminated``. With K
costs the cost GAE runs on a view whose done flags are expanded to ``[N, T, K]``: elementwise in K, each
cost's own GAE (to float32 rounding, as the convolution that sums it may pick another kernel for another batch:
tests/test_cost_vector.py).
"""

from __future__ import annotations

from typing import Protocol

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.objectives.value import GAE

from cmdp_rl.rollout import keys


class Valuing(Protocol):
    """What GAE asks of an agent: each critic's values on a batch (``policies.agent.Agent.rollout_values``, and a
    population's ``PopulationAgent``'s)."""

    def rollout_values(self, batch: TensorDictBase, signal: str) -> tuple[torch.Tensor, torch.Tensor]:
        """``(V(obs), V(next obs))`` of ``signal``'s critic on ``batch`` ``[N, T]``."""
        ...


def _gae(gamma: float, lmbda: float, signal: str) -> GAE:
    gae = GAE(gamma=gamma, lmbda=lmbda, value_network=None)
    reward, value, advantage, target = keys.SIGNALS[signal]
    gae.set_keys(reward=reward, value=value, advantage=advantage, value_target=target, done=keys.DONE)
    gae.set_keys(terminated=keys.TERMINATED)
    return gae


class TwinGAE:
    def __init__(self, gamma: float, cost_gamma: float, lmbda: float) -> None:
        self.reward, self.cost = _gae(gamma, lmbda, "reward"), _gae(cost_gamma, lmbda, "cost")

    @torch.no_grad()
    def __call__(self, batch: TensorDictBase, agent: Valuing) -> TensorDictBase:
        """Write both critics' values, advantages and value targets into ``batch`` ``[N, T]``."""
        for signal in ("reward", "cost"):
            value_key = keys.SIGNALS[signal][1]
            values, next_values = agent.rollout_values(batch, signal)
            batch.set(value_key, values)
            batch.set((keys.NEXT, value_key), next_values)
        self.reward(batch)
        self._cost_gae(batch)
        return batch

    def _cost_gae(self, batch: TensorDictBase) -> None:
        k = batch.get((keys.NEXT, keys.COST)).shape[-1]
        if k == 1:
            self.cost(batch)
            return
        nxt = batch.get(keys.NEXT)
        flags = {(keys.NEXT, f): nxt.get(f).expand(*batch.shape, k) for f in (keys.DONE, keys.TERMINATED)}
        view = TensorDict(
            {
                keys.COST_VALUE: batch.get(keys.COST_VALUE),
                (keys.NEXT, keys.COST_VALUE): nxt.get(keys.COST_VALUE),
                (keys.NEXT, keys.COST): nxt.get(keys.COST),
                **flags,
            },
            batch_size=batch.shape,
            device=batch.device,
        )
        self.cost(view)
        batch.set(keys.COST_ADVANTAGE, view.get(keys.COST_ADVANTAGE))
        batch.set(keys.COST_VALUE_TARGET, view.get(keys.COST_VALUE_TARGET))


def standardized(x: torch.Tensor, dim: tuple[int, ...] | None = None) -> torch.Tensor:
    """``(x - mean) / (std + 1e-8)``: over all of ``x``, or over ``dim`` (each remaining column on its own)."""
    if dim is None:
        return (x - x.mean()) / (x.std() + 1e-8)
    return (x - x.mean(dim=dim)) / (x.std(dim=dim) + 1e-8)
