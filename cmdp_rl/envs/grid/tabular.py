"""A finite discounted CMDP as explicit arrays, with exact policy evaluation and the unconstrained
optimum; :func:`grid_cmdp` writes the gridworld of ``env.py`` in this form. Conventions (Altman 1999,
discounted criterion): ``P[s, a, s']`` moves to the non-terminal state ``s'``, and a row's missing
mass ends the episode (the grid's goal); ``r[s, a]`` and ``c[k, s, a]`` are one step's expected
reward and costs; ``J(pi) = E[sum_t gamma^t r(s_t, a_t)]`` with ``s_0 ~ mu0``, ``J_c[k]`` likewise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cmdp_rl.envs.grid.env import (
    COST_NAMES,
    DEFAULT_END_PROB,
    DEFAULT_LAYOUT,
    DEFAULT_SLIP,
    MOVES,
    Layout,
    parse_layout,
)


class Sizes:
    """S, A and K of a CMDP held as arrays ``P [S, A, S]`` and ``c [K, S, A]`` (this one, the suite's)."""

    P: np.ndarray
    c: np.ndarray

    @property
    def num_states(self) -> int:
        return self.P.shape[0]

    @property
    def num_actions(self) -> int:
        return self.P.shape[1]

    @property
    def num_costs(self) -> int:
        return self.c.shape[0]


@dataclass(frozen=True, eq=False)
class TabularCMDP(Sizes):
    """``(S, A, P, r, c, mu0, gamma)`` with K cost functions (module docstring)."""

    P: np.ndarray  # [S, A, S], substochastic rows allowed
    r: np.ndarray  # [S, A]
    c: np.ndarray  # [K, S, A]
    mu0: np.ndarray  # [S]
    gamma: float
    cost_names: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class PolicyValue:
    """A policy's exact values (a batch of policies ``[..., S, A]`` adds its leading dimensions)."""

    ret: np.ndarray | float  # J(pi)
    costs: np.ndarray  # [..., K] J_c(pi)
    value: np.ndarray  # [..., S] V^pi
    cost_value: np.ndarray  # [..., K, S]


def evaluate(cmdp: TabularCMDP, policy: np.ndarray) -> PolicyValue:
    """Exact values of a stationary policy ``policy[s, a] = pi(a | s)`` (or a batch ``[..., S, A]``):
    ``V = (I - gamma P_pi)^-1 r_pi``, one linear solve per policy."""
    pi = np.asarray(policy, dtype=np.float64)
    if pi.shape[-2:] != (cmdp.num_states, cmdp.num_actions):
        raise ValueError(f"policy: expected shape [..., {cmdp.num_states}, {cmdp.num_actions}], got {pi.shape}")
    p_pi = np.einsum("...sa,sat->...st", pi, cmdp.P)
    rhs = np.concatenate(
        [np.einsum("...sa,sa->...s", pi, cmdp.r)[..., None], np.einsum("...sa,ksa->...sk", pi, cmdp.c)], axis=-1
    )  # [..., S, 1 + K]
    lhs = np.eye(cmdp.num_states) - cmdp.gamma * p_pi
    values = np.linalg.solve(lhs, rhs)  # [..., S, 1 + K]
    totals = np.einsum("s,...sk->...k", cmdp.mu0, values)
    ret = totals[..., 0]
    return PolicyValue(
        ret=float(ret) if ret.ndim == 0 else ret,
        costs=totals[..., 1:],
        value=values[..., 0],
        cost_value=np.moveaxis(values[..., 1:], -1, -2),
    )


@dataclass(frozen=True, eq=False)
class GridCMDP(TabularCMDP):
    """The gridworld as a :class:`TabularCMDP`: its states are the open cells other than the goal;
    ``arrive[s, a, cell]`` is where one step lands (the goal included), from which the gym env's
    reward (1 at the goal) and cost (the hazard kind of the cell) follow."""

    layout: Layout = None  # type: ignore[assignment]
    state_cells: np.ndarray = None  # type: ignore[assignment]  # [S] cell index of each state
    arrive: np.ndarray = None  # type: ignore[assignment]  # [S, A, num_cells]

    def state_of_cell(self, cell: int) -> int:
        return int(np.flatnonzero(self.state_cells == cell)[0])


def grid_cmdp(
    layout: Sequence[str] = DEFAULT_LAYOUT, slip: float = DEFAULT_SLIP, end_prob: float = DEFAULT_END_PROB
) -> GridCMDP:
    """The gridworld of ``env.py`` with these options, as arrays (``gamma = 1 - end_prob``)."""
    lay = parse_layout(layout)
    state_cells = np.array([n for n in range(lay.num_cells) if n != lay.goal])
    num_actions = len(MOVES)
    arrive = np.zeros((len(state_cells), num_actions, lay.num_cells))
    for s, cell in enumerate(state_cells):
        for a in range(num_actions):
            # intended move with 1 - slip, each perpendicular one with slip / 2 (env.py, step 1)
            for direction, p in ((a, 1.0 - slip), ((a + 1) % 4, slip / 2), ((a + 3) % 4, slip / 2)):
                arrive[s, a, lay.next_cell(int(cell), direction)] += p
    return GridCMDP(
        P=arrive[:, :, state_cells],
        r=arrive[:, :, lay.goal],
        c=np.einsum("san,kn->ksa", arrive, lay.hazards),
        mu0=np.isin(state_cells, lay.starts) / len(lay.starts),
        gamma=1.0 - end_prob,
        cost_names=COST_NAMES,
        layout=lay,
        state_cells=state_cells,
        arrive=arrive,
    )
