"""The Button tasks of ``env=safe_nav`` (``PointButton0`` ... ``CarButton2``) as Safety-Gymnasium 1.0.0
defines them (docs/safe_nav.md, "How it works"): press the goal button, avoid hazards, gremlins and wrong buttons."""

from __future__ import annotations

from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav.arrays import distance
from cmdp_rl.envs.safe_nav.goal import NavTask
from cmdp_rl.envs.safe_nav.layout import LayoutSampler
from cmdp_rl.envs.safe_nav.lidar import pseudo_lidars
from cmdp_rl.envs.safe_nav.spec import REWARD_CLIP
from cmdp_rl.envs.safe_nav.world import NavWorlds

BUTTON_DELAY = 10  # steps after a press during which buttons are neither seen nor cost


class ButtonTask(NavTask):
    """The Button task's state and logic for N envs."""

    from_layout = ("buttons", "hazards")
    saved = ("goal", "last_dist", "goal_button", "timer")

    def __init__(self, worlds: NavWorlds, sampler: LayoutSampler) -> None:
        super().__init__(worlds, sampler, 2 + (worlds.spec.level > 0) * 2)
        n = worlds.num_envs
        self.goal = np.zeros((n, 2))
        self.buttons = np.zeros((n, self.spec.buttons, 2))
        self.hazards = np.zeros((n, self.spec.hazards, 2))
        self.goal_button = np.zeros(n, dtype=np.int64)
        self.timer = np.zeros(n, dtype=np.int64)
        self.last_dist = np.zeros(n)

    def _choose(self, i: int) -> None:
        """A goal button for env ``i``, drawn from its stream; the goal body moves onto it."""
        self.goal_button[i] = self.sampler.choice(i, self.spec.buttons)
        self.goal[i] = self.buttons[i, self.goal_button[i]]
        self.worlds.move_goal(i, self.goal[i])

    def start(self, envs: list[int], layouts: list[dict[str, Any]], world: dict[str, np.ndarray]) -> None:
        super().start(envs, layouts, world)
        for i in envs:
            self._choose(i)
        self.last_dist[envs] = self._dist_goal(envs, world)
        self.timer[envs] = 0

    def lidars(self, envs, world: dict[str, np.ndarray]) -> list[np.ndarray]:
        pos, mat = world["agent_pos"], world["agent_mat"]
        groups = [self.buttons[envs], self.goal[envs, None]]
        if self.spec.level > 0:
            groups += [self.hazards[envs], world["xpos"][:, self.worlds.gremlins, :2]]
        out = pseudo_lidars(groups, pos, mat)
        out[0][self.timer[envs] != 0] = 0.0
        return out

    def _touches(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per env: the robot touches its goal button / another button / a gremlin."""
        w, n = self.worlds, self.worlds.num_envs
        env, g1, g2 = w.contacts()
        robot1, robot2 = w.geom_is_robot[g1], w.geom_is_robot[g2]
        button = np.where(robot2, w.geom_button[g1], np.where(robot1, w.geom_button[g2], -1))
        goal_button = self.goal_button[env]
        goal, wrong, gremlin = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        goal[env[button == goal_button]] = True
        wrong[env[(button >= 0) & (button != goal_button)]] = True
        gremlin[env[(w.geom_is_gremlin[g1] & robot2) | (robot1 & w.geom_is_gremlin[g2])]] = True
        return goal, wrong, gremlin

    def step(self, world: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dist = self._dist_goal(slice(None), world)
        pressed, wrong, gremlin = self._touches()
        reward = np.clip(self.last_dist - dist + pressed * 1.0, -REWARD_CLIP, REWARD_CLIP)
        cost = (self._in_hazard(world) | gremlin | (wrong & (self.timer == 0))) & (self.spec.level > 0)
        self.timer = np.maximum(0, self.timer - 1)
        self.last_dist = dist
        for i in np.flatnonzero(pressed):
            self._choose(i)
            self.timer[i] = BUTTON_DELAY
        if pressed.any():
            self.last_dist[pressed] = distance(self.goal[pressed], world["agent_pos"][pressed, :2])
        return reward, cost, np.zeros(len(dist), dtype=bool)
