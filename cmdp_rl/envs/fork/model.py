"""The fork CMDP as arrays: three routes from a start to a goal, each with its own hazard, and an
optimum that is a randomised policy (docs/fork.md). ``env.py`` steps it in torch; ``task.py`` solves it.

State 0 is the fork, where every episode starts; action ``r`` (0, 1, 2) enters route ``r``, whose
cells lead to the goal in ``lengths[r]`` moves: route 0 (the short one) runs over hazard ``a`` cells,
route 1 over hazard ``b`` cells, route 2 (the long one) is hazard-free. On a route cell, action 0
advances one cell and actions 1 and 2 wait. Arriving at (or waiting on) a hazard cell costs 1 of its
kind; arriving at the goal pays ``goal_reward`` and ends the episode. After every other step the
episode ends with probability ``end_prob``, so the discounted values with ``gamma = 1 - end_prob``
are the episode totals (``grid/env.py`` says why). ``num_costs=2`` reports ``hazard_a`` and
``hazard_b``; ``num_costs=1`` one cost, ``hazard``, the two kinds together.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cmdp_rl.envs.grid.tabular import TabularCMDP

DEFAULT_LENGTHS = (3, 5, 8)
DEFAULT_GOAL_REWARD = 10.0
DEFAULT_END_PROB = 0.1
NUM_ACTIONS = 3
ADVANCE = 0  # on a route cell; the other actions wait
COST_NAMES = {1: ("hazard",), 2: ("hazard_a", "hazard_b")}
ROUTE_HAZARD = (0, 1, None)  # the hazard kind (a, b) of each route's cells; route 2 has none
GOAL = -1  # next_state's entry for a move that arrives at the goal


@dataclass(frozen=True, eq=False)
class ForkCMDP(TabularCMDP):
    """The fork as a :class:`TabularCMDP` (the random end in ``gamma``), with what the batched env
    steps: ``next_state[s, a]`` (``GOAL`` at the goal), and each state's route (``-1``: the fork)."""

    next_state: np.ndarray = None  # type: ignore[assignment]  # [S, A] int
    route: np.ndarray = None  # type: ignore[assignment]  # [S] int, -1 at the fork
    lengths: tuple[int, ...] = DEFAULT_LENGTHS

    @property
    def obs_dim(self) -> int:
        """One-hot over the states and the goal (the goal is the last entry)."""
        return self.num_states + 1


def fork_cmdp(
    num_costs: int = 1,
    lengths: Sequence[int] = DEFAULT_LENGTHS,
    goal_reward: float = DEFAULT_GOAL_REWARD,
    end_prob: float = DEFAULT_END_PROB,
) -> ForkCMDP:
    """The fork with these options as arrays (module docstring)."""
    if num_costs not in COST_NAMES:
        raise ValueError(f"fork num_costs must be 1 or 2, got {num_costs!r}")
    if len(lengths) != 3 or any(int(n) < 1 for n in lengths):
        raise ValueError(f"fork lengths must be three positive move counts, got {list(lengths)!r}")
    lengths = tuple(int(n) for n in lengths)
    # States: the fork, then each route's cells in order (a route of n moves has n - 1 cells).
    cell = {}
    route = [-1]
    for r, n in enumerate(lengths):
        for j in range(n - 1):
            cell[r, j] = len(route)
            route.append(r)
    num_s = len(route)
    nxt = np.full((num_s, NUM_ACTIONS), GOAL, dtype=np.int64)
    hazard = np.zeros((2, num_s, NUM_ACTIONS))  # [kind, s, a]: the cost of arriving where (s, a) leads

    def arrive(s: int, a: int, r: int, j: int) -> None:  # (s, a) leads to position j of route r
        if j == lengths[r] - 1:
            return  # the goal: GOAL already, no cost
        nxt[s, a] = cell[r, j]
        if ROUTE_HAZARD[r] is not None:
            hazard[ROUTE_HAZARD[r], s, a] = 1.0

    for a in range(NUM_ACTIONS):
        arrive(0, a, a, 0)
    for (r, j), s in cell.items():
        for a in range(NUM_ACTIONS):
            arrive(s, a, r, j + 1 if a == ADVANCE else j)
    P = np.zeros((num_s, NUM_ACTIONS, num_s))
    s_idx, a_idx = np.nonzero(nxt != GOAL)
    P[s_idx, a_idx, nxt[s_idx, a_idx]] = 1.0
    mu0 = np.zeros(num_s)
    mu0[0] = 1.0
    return ForkCMDP(
        P=P,
        r=np.where(nxt == GOAL, float(goal_reward), 0.0),
        c=hazard if num_costs == 2 else hazard.sum(0, keepdims=True),
        mu0=mu0,
        gamma=1.0 - float(end_prob),
        cost_names=COST_NAMES[num_costs],
        next_state=nxt,
        route=np.array(route),
        lengths=lengths,
    )
