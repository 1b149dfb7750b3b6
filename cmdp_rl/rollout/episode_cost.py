"""The estimate of J_c, the expected undiscounted episode cost, that every constrained algorithm
compares with its budget d: one definition, so that PPO-Lagrangian's lambda, PID's error and CPO's
constraint all read the same number.

Per iteration:
1. episodes ended in this batch: the mean cost (and length) of those episodes;
2. none ended (episodes longer than a rollout, as on MuJoCo with 1000-step episodes and 256-step
   rollouts): the mean of the last ``window`` episodes that ended in earlier batches (a running
   window, by default one episode per env);
3. none has ended yet in the run: the mean cost so far of the running episodes, a lower bound.

So the estimate exists at every iteration and a multiplier moves every iteration (before, PPO's
lambda stood still in a batch without a finished episode, about three iterations in four on MuJoCo,
while CPO reused its last estimate). Where episodes end in every batch, case 1 is what PPO and
CPO always used: their numbers are unchanged (tests/test_golden.py).

With K costs the estimate is per constraint, from the same episodes: ``costs`` has K entries.
"""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

import torch
from tensordict import TensorDictBase

from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import finished_episodes

FINISHED, WINDOW, RUNNING = "finished", "window", "running"


class EpisodeCost(NamedTuple):
    costs: tuple[float, ...]  # J_c estimate, one per constraint
    length: float  # mean episode length of the same episodes
    source: str  # FINISHED, WINDOW or RUNNING (see the module's docstring)

    @property
    def cost(self) -> float:
        """The J_c estimate of an env with one constraint."""
        if len(self.costs) != 1:
            raise ValueError(f"EpisodeCost.cost: there are {len(self.costs)} constraints; read costs")
        return self.costs[0]


class EpisodeCostEstimate:
    """J_c per iteration from the collector's batches (see the module's docstring)."""

    def __init__(self, window: int | None = None) -> None:
        """``window``: episodes kept; None: one per env, the first batch's ``num_envs``."""
        if window is not None and window < 1:
            raise ValueError(f"window must be a positive integer, got {window}")
        self.window = window
        # (cost_0, ..., cost_{K-1}, length) per episode: with K = 1, (cost, length) as it always was.
        self._recent: deque[tuple[float, ...]] = deque(maxlen=window)

    def update(self, batch: TensorDictBase) -> EpisodeCost:
        if self.window is None:
            self.window = batch.shape[0]
            self._recent = deque(self._recent, maxlen=self.window)
        eps = finished_episodes(batch)
        cost, length = eps["cost"], eps["length"]  # [E, K], [E]
        if length.numel():
            self._recent.extend((*c, n) for c, n in zip(cost.tolist(), length.tolist()))
            return EpisodeCost(_column_means(cost), length.mean().item(), FINISHED)
        if self._recent:
            recent = torch.tensor(list(self._recent), dtype=torch.float64)
            return EpisodeCost(_column_means(recent[:, :-1]), recent[:, -1].mean().item(), WINDOW)
        last = batch.get(keys.NEXT)[:, -1]
        return EpisodeCost(
            _column_means(last.get(keys.EPISODE_COST).float()),
            last.get(keys.EPISODE_LENGTH).float().mean().item(),
            RUNNING,
        )

    def state_dict(self) -> dict:
        return {"recent": list(self._recent), "window": self.window}

    def load_state_dict(self, state: dict) -> None:
        self.window = state.get("window", self.window)
        self._recent = deque((tuple(r) for r in state.get("recent", [])), maxlen=self.window)


def _column_means(x: torch.Tensor) -> tuple[float, ...]:
    """The mean of each column of ``[rows, K]``, each reduced as one column on its own."""
    return tuple(x[:, k].mean().item() for k in range(x.shape[1]))


__all__ = ["FINISHED", "RUNNING", "WINDOW", "EpisodeCost", "EpisodeCostEstimate"]
