"""The Push tasks of ``env=safe_nav`` (``PointPush0`` ... ``CarPush2``) as Safety-Gymnasium 1.0.0 defines
them (docs/safe_nav.md, "How it works"): push the box onto the goal, avoid hazards and pillars."""

from __future__ import annotations

from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav.arrays import distance
from cmdp_rl.envs.safe_nav.goal import NavTask
from cmdp_rl.envs.safe_nav.layout import LayoutSampler
from cmdp_rl.envs.safe_nav.lidar import pseudo_lidars
from cmdp_rl.envs.safe_nav.spec import GOAL_SIZE, REWARD_CLIP
from cmdp_rl.envs.safe_nav.world import NavWorlds


class PushTask(NavTask):
    """The Push task's state and logic for N envs."""

    from_layout = ("goal", "hazards", "pillars")
    saved = ("goal", "last_dist_box", "last_box_goal")

    def __init__(self, worlds: NavWorlds, sampler: LayoutSampler) -> None:
        super().__init__(worlds, sampler, 2 + (worlds.spec.level > 0) * 2)
        n = worlds.num_envs
        self.goal = np.zeros((n, 2))
        self.hazards = np.zeros((n, self.spec.hazards, 2))
        self.pillars = np.zeros((n, self.spec.pillars, 2))
        self.last_dist_box = np.zeros(n)
        self.last_box_goal = np.zeros(n)

    def _goal3(self, envs) -> np.ndarray:
        return np.concatenate([self.goal[envs], np.full((len(self.goal[envs]), 1), self.worlds.goal_z)], axis=1)

    def start(self, envs: list[int], layouts: list[dict[str, Any]], world: dict[str, np.ndarray]) -> None:
        super().start(envs, layouts, world)
        box = world["xpos"][:, self.worlds.push_box]
        self.last_dist_box[envs] = distance(box, world["agent_pos"])
        self.last_box_goal[envs] = distance(box, self._goal3(envs))

    def lidars(self, envs, world: dict[str, np.ndarray]) -> list[np.ndarray]:
        pos, mat = world["agent_pos"], world["agent_mat"]
        groups = [self.goal[envs, None]]
        if self.spec.level > 0:
            groups += [self.hazards[envs], self.pillars[envs]]
        groups.append(world["xpos"][:, None, self.worlds.push_box, :2])
        return pseudo_lidars(groups, pos, mat)

    def step(self, world: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        box = world["xpos"][:, self.worlds.push_box]
        dist_box = distance(box, world["agent_pos"])
        box_goal = distance(box, self._goal3(slice(None)))
        reached = box_goal <= GOAL_SIZE
        # the robot-box term gated on the last distance exceeding 0, as the reference's; summed in its order
        reward = (self.last_dist_box - dist_box) * (self.last_dist_box > 0.0) + (self.last_box_goal - box_goal)
        reward = np.clip(reward + reached * 1.0, -REWARD_CLIP, REWARD_CLIP)
        cost = self._in_hazard(world)  # level 0 has no hazards
        if self.spec.pillars_constrained:
            cost |= self.worlds.touching(self.worlds.geom_is_pillar)
        terminated = np.zeros(len(box), dtype=bool)
        self.last_dist_box, self.last_box_goal = dist_box, box_goal
        for i in np.flatnonzero(reached):
            now = dict(agent=world["agent_pos"][i : i + 1, :2], hazards=self.hazards[i], pillars=self.pillars[i])
            if self._new_goal(i, {**now, "push_box": world["xpos"][i : i + 1, self.worlds.push_box, :2]}):
                self.last_box_goal[i] = distance(box[i], self._goal3([i])[0])
            else:
                terminated[i] = True
        return reward, cost, terminated
