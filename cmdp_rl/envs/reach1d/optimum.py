"""Exact penalty-optimal plans on Reach1D's true-state dynamics, by dynamic programming on a grid.

Used to answer the seed's second exercise from the env's parameters, with no learning involved:
for the reward-penalty objective ``sum_t gamma^t r_t - lambda * sum_t gamma_c^t c_t``, from which
start states does the optimal policy cross the wall (``wall="pass"``: a crossing move goes
through and costs 1), and for which lambda does that stop?

Model (stated, because the learned agent does not share all of it):

- the planner sees the true position x (the agent sees x + noise, sigma = ``obs_noise``); the
  dynamics are deterministic, so an optimal plan is a path;
- positions and moves live on a grid of step ``resolution`` (default 0.001); moves are integers in
  ``[-max_speed, max_speed]`` (the env's action bound);
- the wall point itself belongs to the far side (a move onto x = wall_x counts as a crossing).
  This closes the seed's float edge (landing exactly on the wall, then passing at no cost), which
  float32 actions do not hit (see ``reach1d.py``);
- the time limit ``max_steps`` bounds the planning horizon.

Why the thresholds have a closed form: the penalized value of crossing at step t is
``D_t(x0) - lambda * gamma_c^t``, where ``D_t`` is the best reward of a path that crosses exactly
at step t, and not crossing is worth ``N(x0)``. So the optimal plan crosses iff
``lambda < lambda*(x0) = max_t (D_t(x0) - N(x0)) / gamma_c^t`` (0 if crossing never pays). Both
``N`` and every ``D_t`` are one backward sweep each over the grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Union

import numpy as np

from cmdp_rl.envs.reach1d.env import GOAL_TOLERANCE, MAX_SPEED


class Reach1DConfig(Protocol):
    """The options the planner reads (``reach1d_task.Reach1DConfig`` has them; that class calls
    this module's solver, so it is not imported here)."""

    wall_x: float
    goal: float
    max_steps: int
    wall: str
    start: Union[float, list]


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
        return _start_indices(self.x, start)

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


def _start_indices(x: np.ndarray, start: float | list | tuple) -> np.ndarray:
    """Grid indices of a start distribution: a point (its nearest grid point), or ``[low, high]``
    (uniform), the latter as the grid cells' midpoints, so that each cell carries its share of the mass."""
    u = x[1] - x[0]
    if isinstance(start, (list, tuple)) and start[1] > start[0]:
        cells = max(1, int(round((start[1] - start[0]) / u)))
        mid = start[0] + (np.arange(cells) + 0.5) * (start[1] - start[0]) / cells
        return np.clip(np.floor(mid / u + 1e-9).astype(int), 0, len(x) - 1)
    point = float(start[0] if isinstance(start, (list, tuple)) else start)
    return np.array([int(np.clip(np.rint(point / u), 0, len(x) - 1))])


def _grid(env: Reach1DConfig, resolution: float):
    """Transition tables over grid positions k (x = k * resolution) and moves m."""
    n = int(round(1.0 / resolution))
    wall = env.wall_x / resolution
    goal = env.goal / resolution
    speed = int(round(MAX_SPEED / resolution))
    k = np.arange(n + 1)[:, None]
    proposed = np.clip(k + np.arange(-speed, speed + 1)[None, :], 0, n)
    crossed = (k >= wall) != (proposed >= wall)
    nxt = np.where(crossed & (env.wall == "block"), k, proposed)
    dist = np.abs(goal - nxt) * resolution
    terminal = dist < GOAL_TOLERANCE
    reward = np.abs(goal - k) * resolution - dist + terminal * 1.0
    return k[:, 0] * resolution, crossed, nxt, terminal, reward


def crossing_thresholds(
    env: Reach1DConfig, gamma: float, cost_gamma: float | None = None, resolution: float = 1e-3
) -> CrossingThresholds:
    """Penalty thresholds ``lambda*(x0)`` for every grid start, from ``env``'s parameters."""
    cost_gamma = gamma if cost_gamma is None else cost_gamma
    x, crossed, nxt, terminal, reward = _grid(env, resolution)
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
    x, crossed, nxt, terminal, reward = _grid(env, resolution)
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


@dataclass(frozen=True)
class ConstrainedOptimum:
    """The best expected return of any policy whose expected cost is at most the budget.

    ``value``: that return; ``cost``: the optimal policy's expected cost (at most the budget; below
    it when the budget does not bind); ``penalty``: the Lagrange multiplier at which the optimal
    mixture is a tie between its plans (0 when the budget does not bind)."""

    value: float
    cost: float
    penalty: float
    cost_limit: float


def best_returns_by_crossings(
    env: Reach1DConfig, max_crossings: int, gamma: float = 1.0, resolution: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """``V[k, i]``: the best return (discount ``gamma``) from grid start ``x[i]`` of a path with at
    most ``k`` crossings, ``k = 0 .. max_crossings``; by backward induction over ``env.max_steps``
    steps on the state (position, crossings left). Returns ``(x, V)``."""
    x, crossed, nxt, terminal, reward = _grid(env, resolution)
    cont = ~terminal
    value = np.zeros((max_crossings + 1, len(x)))
    for _ in range(env.max_steps):
        new = np.empty_like(value)
        for k in range(max_crossings + 1):
            stay = np.where(crossed, -np.inf, reward + gamma * cont * value[k][nxt])
            if k > 0:  # a crossing move spends one of the k
                stay = np.where(crossed, reward + gamma * cont * value[k - 1][nxt], stay)
            new[k] = stay.max(axis=1)
        value = new
    return x, value


def constrained_optimum(
    env: Reach1DConfig, cost_limit: float, gamma: float = 1.0, resolution: float = 1e-3
) -> ConstrainedOptimum:
    """The constrained optimum of Reach1D: max E[return] s.t. E[crossings] <= ``cost_limit``, over
    all policies of the true state (randomised ones included), from ``env.start``.

    Both sums are undiscounted by default (``gamma=1``), as ``eval.json`` reports them. The planner
    sees the true position, so for the learning agent, which sees a noisy reading, this is an upper
    bound. Each crossing costs exactly 1, so a plan's cost is its number of crossings k, and from
    each start the plans worth considering are the best with at most k crossings, ``V_k``. A
    randomised policy mixes them, per start, with the budget holding on average over starts: a
    linear programme whose value, by its duality (Altman 1999, *Constrained Markov Decision
    Processes*, ch. 3), is ``min_{lambda >= 0} lambda * d + E_start max_k (V_k - lambda * k)``.
    That function of lambda is convex and piecewise linear, with its kinks at the slopes
    ``(V_j - V_k) / (j - k)``: its minimum is at one of them (or at 0).

    k runs up to ``ceil(cost_limit) + 1`` and on while another crossing still gains anywhere (plans
    with more crossings than the budget can still be part of a mixture)."""
    if not (cost_limit >= 0 and math.isfinite(cost_limit)):
        raise ValueError(f"constrained_optimum: cost_limit must be a finite number >= 0, got {cost_limit}")
    k_max = int(math.ceil(cost_limit)) + 1
    while True:
        x, value = best_returns_by_crossings(env, k_max, gamma, resolution)
        if k_max >= env.max_steps or np.all(value[-1] <= value[-2] + 1e-12):
            break
        k_max *= 2
    v = value[:, _start_indices(x, env.start)]  # [k, starts]
    k = np.arange(v.shape[0])[:, None]
    with np.errstate(invalid="ignore"):  # -inf - -inf where a start has no path with k crossings
        slopes = (v[:, None, :] - v[None, :, :]) / (k[:, None] - k[None, :] + np.eye(len(k))[:, :, None])
    candidates = np.unique(np.concatenate([[0.0], slopes[np.isfinite(slopes) & (slopes > 0)]]))

    def dual(lam: np.ndarray) -> np.ndarray:
        return lam * cost_limit + (v[None] - lam[:, None, None] * k[None]).max(axis=1).mean(axis=1)

    duals = np.concatenate([dual(c) for c in np.array_split(candidates, max(1, len(candidates) // 256))])
    best = int(np.argmin(duals))
    lam = float(candidates[best])
    # The optimal mixture's cost: the budget where it binds, else the unconstrained plans' cost.
    if lam == 0.0:
        top = (v >= v.max(axis=0, keepdims=True) - 1e-12).argmax(axis=0)  # fewest crossings among the best
        cost = float(top.mean())
    else:
        cost = float(cost_limit)
    return ConstrainedOptimum(value=float(duals[best]), cost=cost, penalty=lam, cost_limit=float(cost_limit))
