"""The Push tasks of ``env=safe_nav`` (``PointPush0`` ... ``CarPush2``): push the box onto the goal.

As Safety-Gymnasium 1.0.0 defines them (facts from its source, our code): reward = (last distance
robot-box - distance now) + (last distance box-goal - distance now) + 1 when the box reaches the
goal (box-goal distance <= 0.3), clipped to [-10, 10]. Both distances are 3-D, between body
positions (the goal's centre is 0.16 above the floor, so the box-goal distance never falls below
that height difference). When the box reaches the goal a new goal is drawn, clear of where the
robot, hazards, pillars and box are now; if none is found the episode terminates. Cost (levels 1,
2) = 1 on a step where the robot is inside a hazard (xy distance < 0.3) or, at level 2, touches a
pillar. Observation after the robot's sensors: the 16-bin pseudo-lidar (range 3) of the goal, then
(levels 1, 2) of the hazards and the pillars, then of the box. Episodes truncate at 1000 steps.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav.layout import LayoutSampler
from cmdp_rl.envs.safe_nav.lidar import pseudo_lidars
from cmdp_rl.envs.safe_nav.spec import GOAL_SIZE
from cmdp_rl.envs.safe_nav.world import NavWorlds

EPISODE = 1000
REWARD_CLIP = 10.0


def _dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sqrt(np.sum(np.square(a - b), axis=-1))


class PushTask:
    """The Push task's state and logic for N envs."""

    episode = EPISODE

    def __init__(self, worlds: NavWorlds, sampler: LayoutSampler) -> None:
        self.worlds, self.sampler, self.spec = worlds, sampler, worlds.spec
        n = worlds.num_envs
        self.lidar_groups = 2 + (self.spec.level > 0) * 2
        self.goal = np.zeros((n, 2))
        self.hazards = np.zeros((n, self.spec.hazards, 2))
        self.pillars = np.zeros((n, self.spec.pillars, 2))
        self.last_dist_box = np.zeros(n)
        self.last_box_goal = np.zeros(n)
        # the keep-outs a new goal keeps from the robot, hazards, pillars and box (as placed)
        self.keepout = {kind: k for kind, k, _ in sampler.objects}

    def _goal3(self, envs) -> np.ndarray:
        return np.concatenate([self.goal[envs], np.full((len(self.goal[envs]), 1), self.worlds.goal_z)], axis=1)

    def start(self, envs: list[int], layouts: list[dict[str, Any]], world: dict[str, np.ndarray]) -> None:
        for i, layout in zip(envs, layouts):
            self.goal[i] = layout["goal"]
            self.hazards[i] = layout["hazards"]
            self.pillars[i] = layout["pillars"]
        box = world["xpos"][:, self.worlds.push_box]
        self.last_dist_box[envs] = _dist(box, world["agent_pos"])
        self.last_box_goal[envs] = _dist(box, self._goal3(envs))

    def lidars(self, envs, world: dict[str, np.ndarray]) -> list[np.ndarray]:
        pos, mat = world["agent_pos"], world["agent_mat"]
        groups = [self.goal[envs, None]]
        if self.spec.level > 0:
            groups += [self.hazards[envs], self.pillars[envs]]
        groups.append(world["xpos"][:, None, self.worlds.push_box, :2])
        return pseudo_lidars(groups, pos, mat)

    def _new_goal(self, i: int, world: dict[str, np.ndarray]) -> bool:
        """The box reached env ``i``'s goal: a new one, clear of where everything is now (False: none)."""
        k = self.keepout
        others = [(*world["agent_pos"][i, :2], k["agent"])]
        others += [(*xy, k["hazards"]) for xy in self.hazards[i]] + [(*xy, k["pillars"]) for xy in self.pillars[i]]
        others.append((*world["xpos"][i, self.worlds.push_box, :2], k["push_box"]))
        goal = self.sampler.goal(i, others, k["goal"])
        if goal is None:
            return False
        self.goal[i] = goal
        self.worlds.move_goal(i, goal)
        return True

    def step(self, world: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        box = world["xpos"][:, self.worlds.push_box]
        dist_box = _dist(box, world["agent_pos"])
        box_goal = _dist(box, self._goal3(slice(None)))
        reached = box_goal <= GOAL_SIZE
        # the robot-box term is gated on the last distance exceeding 0 (the reference's null
        # distance, 0 here); summed in the reference's order
        reward = (self.last_dist_box - dist_box) * (self.last_dist_box > 0.0) + (self.last_box_goal - box_goal)
        reward = np.clip(reward + reached * 1.0, -REWARD_CLIP, REWARD_CLIP)
        cost = np.zeros(len(box), dtype=bool)
        if self.spec.level > 0:
            agent_xy = world["agent_pos"][:, None, :2]
            cost = np.any(_dist(self.hazards, agent_xy) < self.spec.hazard_size, axis=-1)
        if self.spec.pillars_constrained:
            cost |= self.worlds.touching(self.worlds.geom_is_pillar)
        terminated = np.zeros(len(box), dtype=bool)
        self.last_dist_box, self.last_box_goal = dist_box, box_goal
        for i in np.flatnonzero(reached):
            if self._new_goal(i, world):
                self.last_box_goal[i] = _dist(box[i], self._goal3([i])[0])
            else:
                terminated[i] = True
        return reward, cost, terminated

    def state_dict(self) -> dict[str, Any]:
        return {
            "goal": self.goal.copy(),
            "last_dist_box": self.last_dist_box.copy(),
            "last_box_goal": self.last_box_goal.copy(),
        }

    def load_state_dict(self, state: dict[str, Any], layouts: list[dict[str, Any]]) -> None:
        for i, layout in enumerate(layouts):
            self.hazards[i] = layout["hazards"]
            self.pillars[i] = layout["pillars"]
            self.worlds.move_goal(i, state["goal"][i])
        self.goal[:] = state["goal"]
        self.last_dist_box[:] = state["last_dist_box"]
        self.last_box_goal[:] = state["last_box_goal"]
