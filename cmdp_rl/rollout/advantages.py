"""Twin critics, twin GAEs: advantages and value targets for reward and for cost.

Both GAEs are torchrl's, reading values the critics wrote beforehand (``value_network=None``), so
one critic pass serves both the estimate and the logging. A truncated step (time limit) is not
terminal: GAE bootstraps from ``V(next observation)`` unless ``("next", "terminated")`` is set,
for the reward critic and the cost critic alike.

K costs: the cost critic's values, the costs, and so the cost advantages and targets are
``[N, T, K]``. torchrl's GAE wants every input of one shape, so the cost GAE runs batched over K
on a view whose done/terminated flags are expanded to ``[N, T, K]``: the recursion is elementwise
in K, so each constraint's advantage is exactly the one GAE gives on that cost alone
(``tests/test_cost_vector.py`` checks this bit for bit). K = 1 calls GAE on the batch as before.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.objectives.value import GAE

from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys


class TwinGAE:
    def __init__(self, gamma: float, cost_gamma: float, lmbda: float) -> None:
        self.reward = GAE(gamma=gamma, lmbda=lmbda, value_network=None)
        self.reward.set_keys(
            reward=keys.REWARD,
            value=keys.VALUE,
            advantage=keys.ADVANTAGE,
            value_target=keys.VALUE_TARGET,
            done=keys.DONE,
            terminated=keys.TERMINATED,
        )
        self.cost = GAE(gamma=cost_gamma, lmbda=lmbda, value_network=None)
        self.cost.set_keys(
            reward=keys.COST,
            value=keys.COST_VALUE,
            advantage=keys.COST_ADVANTAGE,
            value_target=keys.COST_VALUE_TARGET,
            done=keys.DONE,
            terminated=keys.TERMINATED,
        )

    @torch.no_grad()
    def __call__(self, batch: TensorDictBase, agent: Agent) -> TensorDictBase:
        """Write values, advantages and value targets of both critics of ``agent`` into ``batch``
        ([N, T]); the values of the observations and next observations come from
        ``Agent.rollout_values``."""
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
    """``(x - mean) / (std + 1e-8)``: over all of ``x``, or over ``dim`` (each remaining column on
    its own). The advantages' normalisation, written once."""
    if dim is None:
        return (x - x.mean()) / (x.std() + 1e-8)
    return (x - x.mean(dim=dim)) / (x.std(dim=dim) + 1e-8)
