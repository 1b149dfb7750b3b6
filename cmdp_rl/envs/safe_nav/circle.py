"""The Circle tasks of ``env=safe_nav`` (``PointCircle0`` ... ``CarCircle2``): run round a circle.

As Safety-Gymnasium 1.0.0 defines them (facts from its source, our code): the robot starts in
``[-0.8, 0.8]^2``; the reward is its angular speed round the origin, damped off the circle of
radius 1.5: ``0.1 * ((-u y + v x) / r) / (1 + |r - 1.5|)``, with (x, y) its position, (u, v) its
velocity (the body's translational Jacobian times the joint velocities) and r = |(x, y)|, clipped
to [-10, 10]. Cost (levels 1, 2) = 1 on a step where |x| > 1.125 (level 2: or |y| > 1.125), the
sigwalls, which have no contacts. Observation after the robot's sensors: a 16-bin pseudo-lidar of
the circle's centre with range 6. No goal and no termination: episodes truncate at 500 steps.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav.lidar import pseudo_lidar
from cmdp_rl.envs.safe_nav.spec import CIRCLE_RADIUS, SIGWALL_AT
from cmdp_rl.envs.safe_nav.world import NavWorlds

EPISODE = 500
REWARD_FACTOR = 0.1
REWARD_CLIP = 10.0
LIDAR_RANGE = 6.0


class CircleTask:
    """The Circle task's logic for N envs (it keeps no state between steps)."""

    episode = EPISODE
    lidar_groups = 1

    def __init__(self, worlds: NavWorlds, sampler: Any = None) -> None:
        self.worlds, self.spec = worlds, worlds.spec
        nv = worlds.models[0].nv
        self._jacp = np.zeros((3, nv))

    def start(self, envs: list[int], layouts: list[dict[str, Any]], world: dict[str, np.ndarray]) -> None:
        pass

    def lidars(self, envs, world: dict[str, np.ndarray]) -> list[np.ndarray]:
        centre = np.zeros((len(world["agent_pos"]), 1, 2))
        return [pseudo_lidar(centre, world["agent_pos"], world["agent_mat"], LIDAR_RANGE)]

    def _velocity(self) -> np.ndarray:
        """Each robot body's linear velocity ``[N, 3]``, computed as the reference computes it
        (``mj_jacBody``, then the Jacobian times qvel with ``np.dot``): a batched product could
        round differently in the last bit."""
        mj, w, jacp = self.worlds.mj, self.worlds, self._jacp
        out = np.empty((w.num_envs, 3))
        for i, (m, d) in enumerate(zip(w.models, w.datas)):
            mj.mj_jacBody(m, d, jacp, None, w.agent)
            out[i] = np.dot(jacp, d.qvel)
        return out

    def step(self, world: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x, y = world["agent_pos"][:, 0], world["agent_pos"][:, 1]
        vel = self._velocity()
        u, v = vel[:, 0], vel[:, 1]
        # numpy's scalar ``y ** 2`` (what the reference computes) is not always ``y * y`` (it
        # differed in the last bit at about one step in 300): the radius is computed as it is there.
        radius = np.array([np.sqrt(a**2 + b**2) for a, b in zip(x, y)])
        reward = ((-u * y + v * x) / radius) / (1 + np.abs(radius - CIRCLE_RADIUS)) * REWARD_FACTOR
        reward = np.clip(reward, -REWARD_CLIP, REWARD_CLIP)
        cost = np.zeros(len(x), dtype=bool)
        if self.spec.sigwalls:
            cost = np.abs(x) > SIGWALL_AT
        if self.spec.sigwalls == 4:
            cost |= np.abs(y) > SIGWALL_AT
        return reward, cost, np.zeros(len(x), dtype=bool)

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any], layouts: list[dict[str, Any]]) -> None:
        pass
