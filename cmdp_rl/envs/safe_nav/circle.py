"""The Circle tasks of ``env=safe_nav`` (``PointCircle0`` ... ``CarCircle2``) as Safety-Gymnasium 1.0.0
defines them (docs/safe_nav.md, "How it works"): run round the circle of radius 1.5, inside the sigwalls."""

from __future__ import annotations

from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav.goal import NavTask
from cmdp_rl.envs.safe_nav.lidar import pseudo_lidar
from cmdp_rl.envs.safe_nav.spec import CIRCLE_RADIUS, REWARD_CLIP, SIGWALL_AT
from cmdp_rl.envs.safe_nav.world import NavWorlds

REWARD_FACTOR = 0.1
LIDAR_RANGE = 6.0


class CircleTask(NavTask):
    """The Circle task's logic for N envs (it keeps no state between steps)."""

    episode = 500

    def __init__(self, worlds: NavWorlds, sampler: Any = None) -> None:
        super().__init__(worlds, sampler, 1)
        self._jacp = np.zeros((3, worlds.models[0].nv))

    def lidars(self, envs, world: dict[str, np.ndarray]) -> list[np.ndarray]:
        centre = np.zeros((len(world["agent_pos"]), 1, 2))
        return [pseudo_lidar(centre, world["agent_pos"], world["agent_mat"], LIDAR_RANGE)]

    def _velocity(self) -> np.ndarray:
        """Each robot body's linear velocity ``[N, 3]``, as the reference computes it (``mj_jacBody``, then
        ``np.dot`` with qvel): a batched product could round differently in the last bit."""
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
        # the reference's numpy scalar ``y ** 2``, which is not always ``y * y`` (docs/safe_nav.md)
        radius = np.array([np.sqrt(a**2 + b**2) for a, b in zip(x, y)])
        reward = ((-u * y + v * x) / radius) / (1 + np.abs(radius - CIRCLE_RADIUS)) * REWARD_FACTOR
        reward = np.clip(reward, -REWARD_CLIP, REWARD_CLIP)
        cost = (np.abs(x) > SIGWALL_AT) & (self.spec.sigwalls > 0)
        if self.spec.sigwalls == 4:
            cost |= np.abs(y) > SIGWALL_AT
        return reward, cost, np.zeros(len(x), dtype=bool)
