"""Reach1D's penalty thresholds, for the seed's second exercise: for the reward-penalty objective
``sum_t gamma^t r_t - lambda * sum_t gamma_c^t c_t``, from which start states does the optimal policy cross
the wall (``wall="pass"``: a crossing move goes through and costs 1), and for which lambda does that stop?
Exact, by dynamic programming on the grid and model of ``cmdp_rl.envs.reach1d.optimum`` (its docstring states
the model); nothing is learned.

Why the thresholds have a closed form: the penalized value of crossing at step t is
``D_t(x0) - lambda * gamma_c^t``, where ``D_t`` is the best reward of a path that crosses exactly
at step t, and not crossing is worth ``N(x0)``. So the optimal plan crosses iff
``lambda < lambda*(x0) = max_t (D_t(x0) - N(x0)) / gamma_c^t`` (0 if crossing never pays). Both
``N`` and every ``D_t`` are one backward sweep each over the grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cmdp_rl.envs.reach1d.env import GOAL_TOLERANCE, MAX_SPEED
from cmdp_rl.envs.reach1d.optimum import grid_tables, start_indices
from cmdp_rl.envs.reach1d.task import Reach1DConfig


@dataclass(frozen=True)
class CrossingThresholds:
    """``threshold[i]``: the penalty below which the optimal plan from ``x[i]`` crosses the wall
    (once); 0 where crossing never pays. At ``lambda == threshold`` the plan is indifferent."""

    x: np.ndarray
    threshold: np.ndarray
    never_cross_value: np.ndarray  # N(x): best discounted reward of a path that never crosses
    gamma: float
    cost_gamma: float

    def at(self, x0: float) -> float:
        """The threshold for one start state (nearest grid point)."""
        return float(self.threshold[self._index(x0)])

    def _index(self, x0: float) -> int:
        return int(np.clip(np.rint(x0 / (self.x[1] - self.x[0])), 0, len(self.x) - 1))

    def starts(self, start: float | list | tuple) -> np.ndarray:
        """Grid indices of a start distribution: a point, or ``[low, high]`` (uniform), the latter
        as the grid cells' midpoints, so that each cell carries its share of the mass."""
        return start_indices(self.x, start)

    def expected_cost(self, start: float | list | tuple, penalty: float | np.ndarray) -> np.ndarray:
        """Expected crossings of the penalty-optimal plan over a start distribution, per penalty.

        Each start's plan is deterministic (cross iff penalty < its threshold), so this is a step
        function of the penalty, with a jump of P(start) at each start's threshold."""
        lam = np.atleast_1d(np.asarray(penalty, dtype=np.float64))
        th = self.threshold[self.starts(start)]
        return (lam[:, None] < th[None, :]).mean(axis=1)

    def jumps(self, start: float | list | tuple) -> list[tuple[float, float]]:
        """The step function's jumps for a start distribution: (threshold, probability mass)."""
        th = self.threshold[self.starts(start)]
        values, counts = np.unique(np.round(th, 9), return_counts=True)
        return [(float(v), float(c / th.size)) for v, c in zip(values, counts) if v > 0]


def crossing_thresholds(
    env: Reach1DConfig, gamma: float, cost_gamma: float | None = None, resolution: float = 1e-3
) -> CrossingThresholds:
    """Penalty thresholds ``lambda*(x0)`` for every grid start, from ``env``'s parameters."""
    cost_gamma = gamma if cost_gamma is None else cost_gamma
    x, crossed, nxt, terminal, reward = grid_tables(env, resolution)
    horizon = env.max_steps
    cont = ~terminal
    # N: best value over paths that never cross (value iteration over the horizon).
    never = np.zeros(len(x))
    for _ in range(horizon):
        never = np.where(crossed, -np.inf, reward + gamma * cont * never[nxt]).max(axis=1)
    # D_t: best value of a path whose first crossing is at step t, never crossing again after it.
    d_t = np.where(crossed, reward + gamma * cont * never[nxt], -np.inf).max(axis=1)
    threshold = np.maximum(0.0, d_t - never)
    for t in range(1, horizon):
        d_t = np.where(crossed | terminal, -np.inf, reward + gamma * d_t[nxt]).max(axis=1)
        with np.errstate(invalid="ignore"):
            gain = (d_t - never) / cost_gamma**t
        threshold = np.maximum(threshold, np.nan_to_num(gain, nan=0.0, neginf=0.0))
    return CrossingThresholds(x, threshold, never, gamma, cost_gamma)


def penalized_crosses(env: Reach1DConfig, penalty: float, gamma: float, resolution: float = 1e-3) -> np.ndarray:
    """Brute force for checking: full value iteration on ``r - penalty * c`` (with
    ``cost_gamma == gamma``); True where the optimal value beats every never-crossing path."""
    x, crossed, nxt, terminal, reward = grid_tables(env, resolution)
    cont = ~terminal
    value = np.zeros(len(x))
    never = np.zeros(len(x))
    for _ in range(env.max_steps):
        value = (reward - penalty * crossed + gamma * cont * value[nxt]).max(axis=1)
        never = np.where(crossed, -np.inf, reward + gamma * cont * never[nxt]).max(axis=1)
    return value > never + 1e-9


def closed_form_threshold(env: Reach1DConfig, gamma: float) -> float:
    """lambda* for a start left of the wall, by hand (``cost_gamma == gamma``, ``wall="pass"``).

    Walking to the wall and stopping is the best path that never crosses; the best crossing path
    walks the same way and then crosses from the wall. They share the prefix, so the choice is made
    at the wall, whatever the start: cross (the crossing move is the first of n full-speed moves
    that bring x within the goal tolerance, (goal - wall) of shaped progress in all and the +1 on
    the n-th) or stop (worth 0). Hence ``lambda* = sum_j gamma^j p_j + gamma^(n-1)``.
    """
    n = math.ceil((env.goal - GOAL_TOLERANCE - env.wall_x) / MAX_SPEED - 1e-9)
    remaining, total = env.goal - env.wall_x, 0.0
    for j in range(n):
        p = min(MAX_SPEED, remaining)
        total += gamma**j * p
        remaining -= p
    return total + gamma ** (n - 1)
