"""Controllers for the Lagrange multiplier lambda of a constrained objective.

The Lagrangian of ``max J_r  s.t.  J_c <= d`` is ``J_r - lambda (J_c - d)``; its dual ascends on
``J_c - d``. Every controller takes the batch's measured episode cost explicitly, keeps
lambda >= 0, and saves its state with ``state_dict``.
"""

from __future__ import annotations

import math


class DualAscent:
    """Projected gradient ascent on the dual: ``lambda <- max(0, lambda + lr * (J_c - d))``.

    As in PPO-Lagrangian (Ray, Achiam, Amodei, "Benchmarking Safe Exploration in Deep RL", 2019).
    """

    def __init__(self, cost_limit: float, lr: float, init: float = 0.0) -> None:
        if init < 0:
            raise ValueError(f"lambda_init must be >= 0, got {init}")
        self.cost_limit = cost_limit
        self.lr = lr
        self.value = float(init)

    def update(self, episode_cost: float) -> float:
        """One ascent step from the mean undiscounted episode cost ``J_c``; returns the new lambda."""
        if not math.isfinite(episode_cost):
            raise ValueError(f"episode_cost must be finite, got {episode_cost}")
        self.value = max(0.0, self.value + self.lr * (episode_cost - self.cost_limit))
        return self.value

    def state_dict(self) -> dict:
        return {"value": self.value}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])
