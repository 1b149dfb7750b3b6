"""Reach1D: the seed's 1-D reach-to-goal task, a POMDP with a separate collision cost (a CMDP).

A point effector at true position ``x`` (hidden) moves by a box-bounded velocity command towards a
goal, with a wall between the start and the goal. The agent sees ``[clip(x + noise, 0, 1), goal]``.
Reward is shaped progress plus 1 on reaching the goal; a move across the wall costs 1 in
``info["cost"]``. With default options the arithmetic is the seed's to the last bit, including its
strict crossing test: an effector that lands on the wall exactly passes on its next move at no cost
(float64 actions of 0.1 land there, 0.1 + 4 * 0.1 == 0.5; the toolkit's float32 actions never do).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

WALL_MODES = ("block", "pass")
MAX_SPEED = 0.1  # action bound: |velocity command| <= 0.1 per step (stored as float32, as the seed)
GOAL_TOLERANCE = 0.02  # the episode terminates when |goal - x| < this


class Reach1D(gym.Env):
    """Seed-exact Reach1D with options: ``obs_noise`` the position sensor's std; ``wall_x``; ``goal``
    (the episode terminates within ``GOAL_TOLERANCE`` of it); ``max_steps`` the time limit; ``wall``
    ``"block"`` (the seed's: a crossing move is cancelled and costs 1) or ``"pass"`` (it goes through
    and costs 1); ``start`` a position (the seed's 0.1) or a ``[low, high]`` pair drawn uniformly at
    every reset; ``probe`` adds a second action entry, > 0 making the step a probe (no motion, half
    the noise) and a third observation entry, the last probe reading (-1 until the first)."""

    # 8 steps a second: a power of two (cmdp_rl/report/video.py's exact_fps)
    metadata = {"render_modes": ["rgb_array"], "render_fps": 8}

    def __init__(
        self,
        obs_noise: float = 0.02,
        wall_x: float = 0.5,
        max_steps: int = 100,
        goal: float = 0.9,
        wall: str = "block",
        start: float | tuple[float, float] | list[float] = 0.1,
        probe: bool = False,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        if wall not in WALL_MODES:
            raise ValueError(f"env.wall must be one of {WALL_MODES}, got {wall!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"Reach1D: render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.obs_noise = obs_noise
        self.wall_x = wall_x
        self.max_steps = max_steps
        self.goal = goal
        self.wall = wall
        self.start = tuple(start) if isinstance(start, (tuple, list)) else float(start)
        self.probe = probe
        # float32 bounds as in the seed: np.clip against them keeps a float32 action float32.
        low, high = [-MAX_SPEED] + ([-1.0] if probe else []), [MAX_SPEED] + ([1.0] if probe else [])
        self.action_space = spaces.Box(np.array(low, dtype=np.float32), np.array(high, dtype=np.float32))
        low, high = [0.0, 0.0] + ([-1.0] if probe else []), [1.0, 1.0] + ([1.0] if probe else [])
        self.observation_space = spaces.Box(np.array(low, dtype=np.float32), np.array(high, dtype=np.float32))

    def _reading(self, noise_std: float) -> float:
        return float(np.clip(self.x + self.np_random.normal(0.0, noise_std), 0.0, 1.0))

    def _obs(self, reading: float) -> np.ndarray:
        if self.probe:
            return np.array([reading, self.goal, self.last_probe], dtype=np.float32)
        return np.array([reading, self.goal], dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if isinstance(self.start, tuple):
            self.x = float(self.np_random.uniform(self.start[0], self.start[1]))
        else:
            self.x = self.start
        self.steps = 0
        self.last_probe = -1.0
        self._seen = (self._reading(self.obs_noise), 0.0)  # (reading, cost) for render()
        return self._obs(self._seen[0]), {"true_x": self.x}

    def step(self, action):
        clipped = np.clip(action, self.action_space.low, self.action_space.high)
        probing = self.probe and float(clipped[1]) > 0.0
        a = 0.0 if probing else float(clipped[0])
        prev_x = self.x
        proposed = np.clip(self.x + a, 0.0, 1.0)
        # Strict test, as the seed: landing exactly on the wall is not a crossing.
        crossed = (prev_x - self.wall_x) * (proposed - self.wall_x) < 0
        cost = 1.0 if crossed else 0.0
        self.x = prev_x if (crossed and self.wall == "block") else proposed
        dist = abs(self.goal - self.x)
        reward = abs(self.goal - prev_x) - dist
        terminated = dist < GOAL_TOLERANCE
        if terminated:
            reward += 1.0
        self.steps += 1
        truncated = self.steps >= self.max_steps
        reading = self._reading(self.obs_noise / 2 if probing else self.obs_noise)
        if probing:
            self.last_probe = reading
        self._seen = (reading, cost)
        info = {"cost": cost, "true_x": self.x}
        return self._obs(reading), float(reward), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """With ``render_mode="rgb_array"``: the current state as an RGB frame (draws no random
        numbers, so rendering leaves the episode as it would have been)."""
        if self.render_mode != "rgb_array":
            return None
        reading, cost = self._seen
        return render_reach1d(self.x, reading, cost > 0, self.steps / self.max_steps, self.wall_x, self.goal)

    def state_dict(self) -> dict[str, Any]:
        """The episode in progress and the env's generator (``env_state.py`` saves it this way)."""
        return {
            "np_random": self.np_random.bit_generator.state,
            "x": getattr(self, "x", None),
            "steps": getattr(self, "steps", None),
            "last_probe": getattr(self, "last_probe", None),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.np_random.bit_generator.state = state["np_random"]
        self.x, self.steps, self.last_probe = state["x"], state["steps"], state["last_probe"]


FRAME_H, FRAME_W = 128, 512  # multiples of 16: video encoders want even sizes, macroblocks of 16
_MARGIN = 16


def render_reach1d(x: float, reading: float, collided: bool, elapsed: float, wall_x: float, goal: float) -> np.ndarray:
    """A ``FRAME_H x FRAME_W`` RGB frame of Reach1D drawn with numpy: the track [0, 1] left to right,
    the wall (dark bar), the goal (green line in its reach band), the true position (blue disc),
    the noisy reading the agent saw (orange tick above the track), a red border on a step that
    crossed the wall (cost 1), and the elapsed fraction of the time limit (grey bar at the bottom)."""
    img = np.full((FRAME_H, FRAME_W, 3), 250, dtype=np.uint8)
    mid = FRAME_H // 2

    def px(pos: float) -> int:
        return _MARGIN + int(round(float(np.clip(pos, 0.0, 1.0)) * (FRAME_W - 2 * _MARGIN - 1)))

    img[mid - 1 : mid + 2, px(0) : px(1) + 1] = 190  # track
    img[24 : FRAME_H - 24, px(goal - GOAL_TOLERANCE) : px(goal + GOAL_TOLERANCE) + 1] = (200, 235, 200)
    img[24 : FRAME_H - 24, px(goal) - 1 : px(goal) + 2] = (40, 150, 40)
    img[16 : FRAME_H - 16, px(wall_x) - 3 : px(wall_x) + 3] = (70, 70, 70)
    r = px(reading)
    img[mid - 26 : mid - 12, max(r - 2, 0) : r + 3] = (240, 140, 20)
    yy, xx = np.ogrid[:FRAME_H, :FRAME_W]
    img[(yy - mid) ** 2 + (xx - px(x)) ** 2 <= 81] = (30, 90, 200)
    img[FRAME_H - 8 : FRAME_H - 4, _MARGIN : px(elapsed) + 1] = 150
    if collided:
        img[:4], img[-4:], img[:, :4], img[:, -4:] = (220, 30, 30), (220, 30, 30), (220, 30, 30), (220, 30, 30)
    return img
