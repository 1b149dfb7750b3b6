"""The Goal tasks of ``env=safe_nav`` (``PointGoal0`` ... ``CarGoal2``) as Safety-Gymnasium 1.0.0 defines
them (docs/safe_nav.md, "How it works"), and :class:`NavTask`, what every family's logic shares."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav.arrays import distance, like, namespace, to_host, zeros
from cmdp_rl.envs.safe_nav.layout import LayoutSampler
from cmdp_rl.envs.safe_nav.lidar import pseudo_lidars
from cmdp_rl.envs.safe_nav.spec import GOAL_SIZE, REWARD_CLIP
from cmdp_rl.envs.safe_nav.world import NavWorlds

VASE_SPEED = 1e-4  # a vase moving at least this fast costs (level 2)


class NavTask:
    """What every family shares: the arrays each layout gives (``from_layout``) and a state saves (``saved``),
    the goal's distance, the hazard cost; a family adds ``step(world) -> (reward, cost, terminated)``, ``lidars``."""

    episode = 1000
    from_layout: tuple[str, ...] = ()
    saved: tuple[str, ...] = ()

    def __init__(self, worlds: NavWorlds, sampler: LayoutSampler, lidar_groups: int) -> None:
        self.worlds, self.sampler, self.spec = worlds, sampler, worlds.spec
        self.lidar_groups = lidar_groups
        self.keepout = {kind: k for kind, k, _ in sampler.objects}  # each kind's, as placed

    def start(self, envs: list[int], layouts: list[dict[str, Any]], world: dict) -> None:
        """New episodes for ``envs`` (their worlds already placed from ``layouts``)."""
        for i, layout in zip(envs, layouts):
            for key in self.from_layout:
                getattr(self, key)[i] = like(layout[key], getattr(self, key))

    def _dist_goal(self, envs, world):
        return distance(self.goal[envs], world["agent_pos"][:, :2])

    def _in_hazard(self, world):
        near = distance(self.hazards, world["agent_pos"][:, None, :2]) < self.spec.hazard_size
        return namespace(near).any(near, axis=-1)  # the reference's cost > 0, as an indicator

    def _new_goal(self, i: int, others: dict[str, Any]) -> bool:
        """Env ``i``'s goal was reached: a new one clear of ``others`` (each kind's xys now), or False if none."""
        clear_of = [(*xy, self.keepout[kind]) for kind, places in others.items() for xy in places]
        goal = self.sampler.goal(i, clear_of, self.keepout["goal"])
        if goal is None:
            return False
        self.goal[i] = like(goal, self.goal)
        self.worlds.move_goal(i, goal)
        return True

    def state_dict(self) -> dict[str, Any]:
        return {key: to_host(getattr(self, key)).copy() for key in self.saved}

    def load_state_dict(self, state: dict[str, Any], layouts: list[dict[str, Any]]) -> None:
        """After the worlds were placed from ``layouts``: the saved arrays (the goals moved since)."""
        NavTask.start(self, range(len(layouts)), layouts, {})
        for key in self.saved:
            getattr(self, key)[:] = like(state[key], getattr(self, key))
        for i in range(len(layouts) if "goal" in self.saved else 0):
            self.worlds.move_goal(i, state["goal"][i])


class GoalTask(NavTask):
    """The Goal task's state and logic for N envs (goal, hazards, last distance to goal)."""

    from_layout = ("goal", "hazards")
    saved = ("goal", "last_dist")

    def __init__(self, worlds: NavWorlds, sampler: LayoutSampler) -> None:
        super().__init__(worlds, sampler, 1 + (worlds.spec.level > 0) * 2)
        n, proto = worlds.num_envs, worlds.proto  # numpy, or torch on the simulation's device
        self.goal = zeros(proto, (n, 2))
        self.hazards = zeros(proto, (n, self.spec.hazards, 2))
        self.last_dist = zeros(proto, (n,))

    def start(self, envs: list[int], layouts: list[dict[str, Any]], world: dict) -> None:
        super().start(envs, layouts, world)
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

    def step(self, world: dict) -> tuple:
        """Reward, cost and terminated of every env after a physics step (``world``: all envs)."""
        xp = namespace(self.goal)
        dist = self._dist_goal(slice(None), world)
        reached = dist <= GOAL_SIZE
        reward = xp.clip(self.last_dist - dist + reached * 1.0, -REWARD_CLIP, REWARD_CLIP)
        cost = self._in_hazard(world)
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
            if self._new_goal(i, {"agent": agent[k : k + 1], "hazards": hazards[k], "vases": vases[k]}):
                offset = to_host(self.goal[i]) - agent[k]
                self.last_dist[i] = math.sqrt(float(np.sum(np.square(offset))))
            else:
                terminated[i] = True
        return reward, cost, terminated
