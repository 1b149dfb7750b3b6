"""Reach1D's exact constrained optimum (the summary's "constrained optimum" line), by dynamic
programming on its true-state dynamics on a grid, from the env's parameters alone. The model: the
planner sees the true position (the agent a noisy reading, so this is an upper bound for it), the
dynamics are deterministic, positions and moves live on a grid of step ``resolution`` (moves within
the env's action bound), the time limit bounds the horizon, and the wall point belongs to the far
side (a move onto x = wall_x crosses: this closes the seed's float edge, ``env.py``, which float32
actions do not hit). The penalty thresholds of the seed's second exercise, on the same grid, are a
study's (``lab/studies/reach1d_thresholds.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from cmdp_rl.envs.reach1d.env import GOAL_TOLERANCE, MAX_SPEED


def start_indices(x: np.ndarray, start: float | list | tuple) -> np.ndarray:
    """Grid indices of a start distribution: a point (its nearest grid point), or ``[low, high]``
    (uniform), the latter as the grid cells' midpoints, so that each cell carries its share of the mass."""
    u = x[1] - x[0]
    if isinstance(start, (list, tuple)) and start[1] > start[0]:
        cells = max(1, int(round((start[1] - start[0]) / u)))
        mid = start[0] + (np.arange(cells) + 0.5) * (start[1] - start[0]) / cells
        return np.clip(np.floor(mid / u + 1e-9).astype(int), 0, len(x) - 1)
    point = float(start[0] if isinstance(start, (list, tuple)) else start)
    return np.array([int(np.clip(np.rint(point / u), 0, len(x) - 1))])


def grid_tables(env: Any, resolution: float):
    """Transition tables over grid positions k (x = k * resolution) and moves m of ``env``'s options
    (a ``Reach1DConfig``: ``wall_x``, ``goal``, ``wall``; the solvers below read ``max_steps`` and ``start`` too)."""
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


@dataclass(frozen=True)
class ConstrainedOptimum:
    """``value``: the best expected return within the budget; ``cost``: the optimal policy's expected
    cost (below the budget where it does not bind); ``penalty``: the Lagrange multiplier at which the
    optimal mixture is a tie between its plans (0 where the budget does not bind)."""

    value: float
    cost: float
    penalty: float
    cost_limit: float


def best_returns_by_crossings(
    env: Any, max_crossings: int, gamma: float = 1.0, resolution: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """``(x, V)``, ``V[k, i]`` the best return (discount ``gamma``) from grid start ``x[i]`` of a path
    with at most ``k <= max_crossings`` crossings, by backward induction on (position, crossings left)."""
    x, crossed, nxt, terminal, reward = grid_tables(env, resolution)
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
    env: Any, cost_limit: float, gamma: float = 1.0, resolution: float = 1e-3
) -> ConstrainedOptimum:
    """max E[return] s.t. E[crossings] <= ``cost_limit`` over all policies of the true state
    (randomised ones included), from ``env.start``; undiscounted by default, as ``eval.json`` reports.

    A plan's cost is its number of crossings k, so from each start the plans worth considering are
    the best with at most k crossings, ``V_k``. A randomised policy mixes them per start, the budget
    holding on average over starts: a linear programme whose value, by its duality (Altman 1999,
    ch. 3), is ``min_{lambda >= 0} lambda * d + E_start max_k (V_k - lambda * k)``, convex and
    piecewise linear in lambda with its kinks at the slopes ``(V_j - V_k) / (j - k)``: its minimum is
    at one of them (or at 0). k runs up to ``ceil(cost_limit) + 1`` and on while another crossing
    still gains anywhere (plans over the budget can still be part of a mixture)."""
    if not (cost_limit >= 0 and math.isfinite(cost_limit)):
        raise ValueError(f"constrained_optimum: cost_limit must be a finite number >= 0, got {cost_limit}")
    k_max = int(math.ceil(cost_limit)) + 1
    while True:
        x, value = best_returns_by_crossings(env, k_max, gamma, resolution)
        if k_max >= env.max_steps or np.all(value[-1] <= value[-2] + 1e-12):
            break
        k_max *= 2
    v = value[:, start_indices(x, env.start)]  # [k, starts]
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
