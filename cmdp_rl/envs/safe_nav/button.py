"""The Button tasks of ``env=safe_nav`` (``PointButton0`` ... ``CarButton2``): press the goal button.

As Safety-Gymnasium 1.0.0 defines them (facts from its source, our code): four buttons (spheres
of radius 0.1 the robot can touch); one of them, drawn uniformly (``RandomState.choice(4)``), is
the goal, marked by the goal body. Reward = (last distance to the goal button - distance now) + 1
on a step where the robot touches it (a contact between the button and a robot geom), clipped to
[-10, 10]; then a new goal button is drawn (it may be the same one) and a 10-step timer starts:
while it runs the button lidar reads zeros and wrong buttons cost nothing. The episode goes on
(1000 steps, no termination). Cost (levels 1, 2) = 1 on a step where the robot is inside a hazard
(xy distance < 0.2), touches a gremlin, or, with the timer at 0, touches a button other than the
goal. Gremlins are boxes welded to mocap bodies that circle round their places (``safe_nav_world``).
Observation after the robot's sensors: the 16-bin pseudo-lidar (range 3) of the buttons, the goal,
then (levels 1, 2) the hazards and the gremlins.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav.layout import LayoutSampler
from cmdp_rl.envs.safe_nav.lidar import pseudo_lidars
from cmdp_rl.envs.safe_nav.spec import HAZARD_SIZE
from cmdp_rl.envs.safe_nav.world import NavWorlds

EPISODE = 1000
REWARD_CLIP = 10.0
BUTTON_DELAY = 10  # steps after a press during which buttons are neither seen nor cost


class ButtonTask:
    """The Button task's state and logic for N envs."""

    episode = EPISODE

    def __init__(self, worlds: NavWorlds, sampler: LayoutSampler) -> None:
        self.worlds, self.sampler, self.spec = worlds, sampler, worlds.spec
        n = worlds.num_envs
        self.lidar_groups = 2 + (self.spec.level > 0) * 2
        self.goal = np.zeros((n, 2))
        self.buttons = np.zeros((n, self.spec.buttons, 2))
        self.hazards = np.zeros((n, self.spec.hazards, 2))
        self.goal_button = np.zeros(n, dtype=np.int64)
        self.timer = np.zeros(n, dtype=np.int64)
        self.last_dist = np.zeros(n)

    def _dist_goal(self, envs, world) -> np.ndarray:
        d = self.goal[envs] - world["agent_pos"][:, :2]
        return np.sqrt(np.sum(np.square(d), axis=-1))

    def _choose(self, i: int) -> None:
        """A goal button for env ``i``, drawn from its stream; the goal body moves onto it."""
        self.goal_button[i] = self.sampler.choice(i, self.spec.buttons)
        self.goal[i] = self.buttons[i, self.goal_button[i]]
        self.worlds.move_goal(i, self.goal[i])

    def start(self, envs: list[int], layouts: list[dict[str, Any]], world: dict[str, np.ndarray]) -> None:
        for i, layout in zip(envs, layouts):
            self.buttons[i] = layout["buttons"]
            self.hazards[i] = layout["hazards"]
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
        """Per env: the robot touches its goal button / another button / a gremlin (every world's
        contacts tested at once)."""
        w = self.worlds
        n = w.num_envs
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
        cost = np.zeros(len(dist), dtype=bool)
        if self.spec.level > 0:
            agent_xy = world["agent_pos"][:, None, :2]
            hazard_dist = np.sqrt(np.sum(np.square(self.hazards - agent_xy), axis=-1))
            cost = np.any(hazard_dist < HAZARD_SIZE, axis=-1) | gremlin | (wrong & (self.timer == 0))
        self.timer = np.maximum(0, self.timer - 1)
        self.last_dist = dist
        for i in np.flatnonzero(pressed):
            self._choose(i)
            self.timer[i] = BUTTON_DELAY
        if pressed.any():
            d = self.goal[pressed] - world["agent_pos"][pressed, :2]
            self.last_dist[pressed] = np.sqrt(np.sum(np.square(d), axis=-1))
        return reward, cost, np.zeros(len(dist), dtype=bool)

    def state_dict(self) -> dict[str, Any]:
        return {
            "goal": self.goal.copy(),
            "last_dist": self.last_dist.copy(),
            "goal_button": self.goal_button.copy(),
            "timer": self.timer.copy(),
        }

    def load_state_dict(self, state: dict[str, Any], layouts: list[dict[str, Any]]) -> None:
        for i, layout in enumerate(layouts):
            self.buttons[i] = layout["buttons"]
            self.hazards[i] = layout["hazards"]
            self.worlds.move_goal(i, state["goal"][i])
        self.goal[:] = state["goal"]
        self.last_dist[:] = state["last_dist"]
        self.goal_button[:] = state["goal_button"]
        self.timer[:] = state["timer"]
