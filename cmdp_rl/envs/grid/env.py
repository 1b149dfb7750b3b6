"""A slippery gridworld with two kinds of hazard: a small CMDP with discrete actions and K = 2
costs whose exact constrained optimum is known (``tabular.py`` writes it as arrays, ``optimum.py``
solves it). The gymnasium env is ``cmdp_rl/Grid-v0`` (registered when this module is imported).
One step:

1. the action picks a direction (0 up, 1 right, 2 down, 3 left); with probability ``slip`` the
   agent moves instead in one of the two perpendicular directions (``slip / 2`` each);
2. a move off the grid or into a wall (``#``) leaves the agent where it is;
3. arriving at the goal (``G``) pays reward 1 and ends the episode; arriving at (or staying on) a
   hazard cell costs 1 of its kind: ``info["cost"] = [on an 'a' cell, on a 'b' cell]``;
4. otherwise the episode ends with probability ``end_prob``.

Why the random end (a termination, and no time limit): an episode's expected undiscounted return and
cost, which the toolkit logs and budgets, are then exactly the ``gamma = 1 - end_prob`` discounted
ones of the grid without it, those of Altman's discounted CMDP and its LP, whose optimum is then what
``eval.json`` should approach. The one-hot observation lets a network represent any randomised policy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

GRID_ID = "cmdp_rl/Grid-v0"
COST_NAMES = ("hazard_a", "hazard_b")
HAZARD_CHARS = ("a", "b")  # the layout character of each cost, in COST_NAMES order
# Directions as (row, col) offsets: up, right, down, left. Perpendicular to d: (d + 1) % 4, (d + 3) % 4.
MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))

# The default grid: three routes from S to G, two past hazards (docs/grid.md, with its optima).
DEFAULT_LAYOUT = (
    ".......",
    ".#bbbb.",
    "S..a..G",
    ".#####.",
    ".#####.",
    ".......",
)
DEFAULT_SLIP = 0.1
DEFAULT_END_PROB = 0.05
# Budgets (expected hazard_a, hazard_b cost per episode) at which both constraints bind and the
# constrained optimum lies strictly between the unconstrained and the hazard-free ones.
DEFAULT_BUDGETS = (0.3, 0.15)


@dataclass(frozen=True, eq=False)
class Layout:
    """A parsed grid: its open cells (row-major, walls left out), the start cells and the goal."""

    rows: int
    cols: int
    cells: tuple[tuple[int, int], ...]  # (row, col) of each open cell; the index is the observation's
    starts: tuple[int, ...]  # cell indices of 'S' (the start is uniform over them)
    goal: int  # cell index of 'G'
    hazards: np.ndarray  # [K, num_cells] 1.0 on the cells of hazard kind k

    @property
    def num_cells(self) -> int:
        return len(self.cells)

    def next_cell(self, cell: int, direction: int) -> int:
        """Where a move in ``direction`` from ``cell`` lands (the same cell if blocked)."""
        r, c = self.cells[cell]
        dr, dc = MOVES[direction]
        return self._index.get((r + dr, c + dc), cell)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_index", {rc: i for i, rc in enumerate(self.cells)})


def parse_layout(layout: Sequence[str]) -> Layout:
    """Parse rows of ``.`` (open), ``#`` (wall), ``S`` (start), ``G`` (goal), ``a``/``b`` (hazards)."""
    rows = [str(r) for r in layout]
    if not rows or any(len(r) != len(rows[0]) for r in rows) or not rows[0]:
        raise ValueError(f"grid layout: rows must be non-empty and of equal length, got {rows!r}")
    bad = sorted({ch for r in rows for ch in r} - set(".#SGab"))
    if bad:
        raise ValueError(f"grid layout: unknown character(s) {bad}; allowed: . # S G a b")
    cells = tuple((i, j) for i, r in enumerate(rows) for j, ch in enumerate(r) if ch != "#")
    kinds = [rows[i][j] for i, j in cells]
    starts = tuple(n for n, ch in enumerate(kinds) if ch == "S")
    goals = [n for n, ch in enumerate(kinds) if ch == "G"]
    if not starts or len(goals) != 1:
        raise ValueError(f"grid layout: needs at least one 'S' and exactly one 'G', got {len(starts)} and {len(goals)}")
    hazards = np.array([[float(ch == h) for ch in kinds] for h in HAZARD_CHARS])
    return Layout(len(rows), len(rows[0]), cells, starts, goals[0], hazards)


class GridWorld(gym.Env):
    """The slippery two-hazard gridworld (module docstring); ``default_budgets``: budgets at which both
    constraints matter on the default grid."""

    # rgb_array: a drawn frame (render_grid below), for gymnasium's RecordVideo; 4 steps a second
    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}
    cost_names = COST_NAMES

    def __init__(
        self,
        layout: Sequence[str] = DEFAULT_LAYOUT,
        slip: float = DEFAULT_SLIP,
        end_prob: float = DEFAULT_END_PROB,
        costs: Sequence[str] = COST_NAMES,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"grid render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        if not 0.0 <= slip <= 1.0:
            raise ValueError(f"grid slip must be in [0, 1], got {slip!r}")
        if not costs or len(set(costs)) != len(costs) or not set(costs) <= set(COST_NAMES):
            raise ValueError(f"grid costs must be distinct names of {COST_NAMES}, got {costs!r}")
        # The costs reported, in this order: a subset makes a K = 1 variant (the hazards stay put).
        self.cost_names = tuple(costs)
        self._cost_rows = [COST_NAMES.index(c) for c in costs]
        if not 0.0 < end_prob <= 1.0:
            raise ValueError(f"grid end_prob must be in (0, 1], got {end_prob!r}")
        self.layout = parse_layout(layout)
        self.slip = float(slip)
        self.end_prob = float(end_prob)
        self.default_budgets = DEFAULT_BUDGETS
        n = self.layout.num_cells
        self.action_space = spaces.Discrete(len(MOVES))
        self.observation_space = spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float32)
        self.cell = self.layout.starts[0]
        self._last_cost = np.zeros(len(COST_NAMES))

    def _obs(self) -> np.ndarray:
        obs = np.zeros(self.layout.num_cells, dtype=np.float32)
        obs[self.cell] = 1.0
        return obs

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        starts = self.layout.starts
        self.cell = starts[int(self.np_random.integers(len(starts)))] if len(starts) > 1 else starts[0]
        self._last_cost = np.zeros(len(COST_NAMES))
        return self._obs(), {"cell": self.cell}

    def step(self, action):
        direction = int(action)
        if not 0 <= direction < len(MOVES):
            raise ValueError(f"grid action must be in 0..{len(MOVES) - 1}, got {action!r}")
        # Three draws every step, in this order, so a seed fixes one stream whatever happens.
        slipped = self.np_random.random() < self.slip
        side = self.np_random.random() < 0.5
        ends = self.np_random.random() < self.end_prob
        if slipped:
            direction = (direction + (1 if side else 3)) % 4
        self.cell = self.layout.next_cell(self.cell, direction)
        at_goal = self.cell == self.layout.goal
        cost = self.layout.hazards[self._cost_rows, self.cell]  # a copy (integer indexing)
        terminated = bool(at_goal or ends)
        self._last_cost = self.layout.hazards[:, self.cell]  # every hazard's, for the frame's border
        info = {"cost": cost, "cell": self.cell, "goal_reached": bool(at_goal)}
        return self._obs(), 1.0 if at_goal else 0.0, terminated, False, info

    def render(self) -> np.ndarray | None:
        """With ``render_mode="rgb_array"``: the grid and the agent as an RGB frame (draws no random
        numbers, so rendering leaves the episode as it would have been)."""
        if self.render_mode != "rgb_array":
            return None
        return render_grid(self.layout, self.cell, self._last_cost)


CELL_PX = 32  # a multiple of 16: video encoders want even sizes, macroblocks of 16
GRID_COLOURS = {
    ".": (245, 245, 245),
    "#": (60, 60, 60),
    "S": (200, 220, 250),
    "G": (60, 170, 60),
    "a": (240, 150, 40),
    "b": (150, 90, 200),
}
AGENT_COLOUR = (30, 90, 200)


def render_grid(layout: Layout, cell: int, cost: np.ndarray) -> np.ndarray:
    """A ``rows * CELL_PX x cols * CELL_PX`` RGB frame drawn with numpy: each cell in its kind's
    colour (``GRID_COLOURS``: walls dark, hazard a orange, hazard b purple, the goal green, the
    start pale blue) with a 1-pixel grey grid line, the agent as a blue disc, and a 3-pixel border
    in the colour of the hazard whose cost the last step paid (hazard a's if both)."""
    img = np.empty((layout.rows * CELL_PX, layout.cols * CELL_PX, 3), dtype=np.uint8)
    img[:] = GRID_COLOURS["#"]
    kinds = {n: "." for n in range(layout.num_cells)}
    kinds.update({n: "S" for n in layout.starts})
    kinds[layout.goal] = "G"
    for k, ch in enumerate(HAZARD_CHARS):
        kinds.update({int(n): ch for n in np.flatnonzero(layout.hazards[k])})
    for n, (r, c) in enumerate(layout.cells):
        img[r * CELL_PX : (r + 1) * CELL_PX, c * CELL_PX : (c + 1) * CELL_PX] = GRID_COLOURS[kinds[n]]
    img[::CELL_PX], img[:, ::CELL_PX] = 180, 180  # grid lines
    r, c = layout.cells[cell]
    yy, xx = np.ogrid[: img.shape[0], : img.shape[1]]
    centre = (r * CELL_PX + CELL_PX // 2, c * CELL_PX + CELL_PX // 2)
    img[(yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 <= (CELL_PX // 3) ** 2] = AGENT_COLOUR
    paid = [ch for k, ch in enumerate(HAZARD_CHARS) if cost[k] > 0]
    if paid:
        edge = GRID_COLOURS[paid[0]]
        img[:3], img[-3:], img[:, :3], img[:, -3:] = edge, edge, edge, edge
    return img


if GRID_ID not in gym.registry:
    gym.register(id=GRID_ID, entry_point="cmdp_rl.envs.grid.env:GridWorld")
