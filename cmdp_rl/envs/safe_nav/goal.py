"""The Goal tasks of ``env=safe_nav`` (``PointGoal0`` ... ``CarGoal2``): reward, cost, goal lidar.

As Safety-Gymnasium 1.0.0 defines them (facts from its source, our code): reward = (last distance
to goal - distance now) + 1 on reaching it (distance <= 0.3), clipped to [-10, 10]; a goal reached
is replaced by a new one (the episode goes on; if no place is found the episode terminates). Cost =
1 on a step where the robot is inside a hazard (xy distance < 0.2) or, at level 2, touches a vase
or a vase moves (speed >= 1e-4); else 0. Observation after the robot's sensors: a 16-bin
pseudo-lidar (range 3) of the goal, then (levels 1, 2) of the hazards and of the vases. Episodes
truncate at 1000 steps.

Written once for both physics backends (``arrays.py``): numpy float64 on ``env.physics=mujoco``,
torch on the simulation's device on ``env.physics=mjwarp``; only the new goal's draw (the layout
sampler's random stream) runs on the host.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav.arrays import like, namespace, to_host, zeros
from cmdp_rl.envs.safe_nav.layout import LayoutSampler
from cmdp_rl.envs.safe_nav.lidar import pseudo_lidars
from cmdp_rl.envs.safe_nav.spec import AGENT_KEEPOUT, GOAL_SIZE, HAZARD_KEEPOUT, HAZARD_SIZE, VASE_KEEPOUT
from cmdp_rl.envs.safe_nav.world import NavWorlds

EPISODE = 1000
REWARD_CLIP = 10.0
VASE_SPEED = 1e-4  # a vase moving at least this fast costs (level 2)


class GoalTask:
    """The Goal task's state and logic for N envs (goal, hazards, last distance to goal)."""

    episode = EPISODE

    def __init__(self, worlds: NavWorlds, sampler: LayoutSampler) -> None:
        self.worlds, self.sampler, self.spec = worlds, sampler, worlds.spec
        n = worlds.num_envs
        self.lidar_groups = 1 + (self.spec.level > 0) * 2
        proto = worlds.proto  # numpy, or torch on the simulation's device
        self.goal = zeros(proto, (n, 2))
        self.hazards = zeros(proto, (n, self.spec.hazards, 2))
        self.last_dist = zeros(proto, (n,))

    def _dist_goal(self, envs, world):
        xp = namespace(self.goal)
        d = self.goal[envs] - world["agent_pos"][:, :2]
        return xp.sqrt(xp.sum(xp.square(d), axis=-1))

    def start(self, envs: list[int], layouts: list[dict[str, Any]], world: dict[str, np.ndarray]) -> None:
        """New episodes for ``envs`` (their worlds already placed from ``layouts``)."""
        for i, layout in zip(envs, layouts):
            self.goal[i] = like(layout["goal"], self.goal)
            self.hazards[i] = like(layout["hazards"], self.goal)
        self.last_dist[envs] = self._dist_goal(envs, world)

    def lidars(self, envs, world: dict) -> list:
        pos, mat = world["agent_pos"], world["agent_mat"]
        groups = [self.goal[envs, None]]
        if self.spec.level > 0:
            groups += [self.hazards[envs], world["xpos"][:, self.worlds.vases, :2]]
        return pseudo_lidars(groups, pos, mat)

    def _vase_cost(self) -> np.ndarray:
        """Level 2: a robot geom touching a vase, or a vase moving, costs."""
        w = self.worlds
        hit = w.touching(w.geom_is_vase)
        speed = np.sqrt(np.sum(np.square(w.qvel(w.vase_dof[:, None] + np.arange(3))), axis=-1))  # [N, vases]
        return hit | np.any(speed >= VASE_SPEED, axis=-1)

    def _new_goal(self, i: int, agent_xy: np.ndarray, hazards: np.ndarray, vases: np.ndarray) -> bool:
        """Env ``i`` reached its goal: a new one, clear of where everything is now (host arrays of
        env ``i``), or False if none is found."""
        others = [(*agent_xy, AGENT_KEEPOUT)]
        others += [(*xy, HAZARD_KEEPOUT) for xy in hazards]
        others += [(*xy, VASE_KEEPOUT) for xy in vases]
        goal = self.sampler.goal(i, others)
        if goal is None:
            return False
        self.goal[i] = like(goal, self.goal)
        self.worlds.move_goal(i, goal)
        return True

    def step(self, world: dict) -> tuple:
        """Reward, cost and terminated of every env after a physics step (``world``: all envs)."""
        every, xp = slice(None), namespace(self.goal)
        dist = self._dist_goal(every, world)
        reached = dist <= GOAL_SIZE
        reward = xp.clip(self.last_dist - dist + reached * 1.0, -REWARD_CLIP, REWARD_CLIP)
        agent_xy = world["agent_pos"][:, None, :2]
        hazard_dist = xp.sqrt(xp.sum(xp.square(self.hazards - agent_xy), axis=-1))
        cost = xp.any(hazard_dist < HAZARD_SIZE, axis=-1)  # the reference's cost > 0, as an indicator
        if self.spec.vases_constrained:
            cost |= self._vase_cost()
        terminated = zeros(dist, (len(dist),), "bool")
        self.last_dist = dist
        hit = np.flatnonzero(to_host(reached))
        if len(hit):  # the sampler runs on the host: what it needs comes over once per step
            agent = to_host(world["agent_pos"][hit, :2])
            hazards = to_host(self.hazards[hit])
            vases = to_host(world["xpos"][hit][:, self.worlds.vases, :2])
        for k, i in enumerate(hit):
            if self._new_goal(i, agent[k], hazards[k], vases[k]):
                offset = to_host(self.goal[i]) - agent[k]
                self.last_dist[i] = math.sqrt(float(np.sum(np.square(offset))))
            else:
                terminated[i] = True
        return reward, cost, terminated

    def state_dict(self) -> dict[str, Any]:
        return {"goal": to_host(self.goal).copy(), "last_dist": to_host(self.last_dist).copy()}

    def load_state_dict(self, state: dict[str, Any], layouts: list[dict[str, Any]]) -> None:
        """After the worlds were placed from ``layouts``: the goals (moved since) and distances."""
        for i, layout in enumerate(layouts):
            self.hazards[i] = like(layout["hazards"], self.goal)
            self.worlds.move_goal(i, state["goal"][i])
        self.goal[:] = like(state["goal"], self.goal)
        self.last_dist[:] = like(state["last_dist"], self.goal)
