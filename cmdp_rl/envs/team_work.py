"""Team work: a two-agent cooperative CMDP with an exact constrained optimum (``env=pettingzoo``'s default;
docs/multi_agent_and_hybrid.md). Two workers act for ``horizon`` steps; each picks ``idle``, ``work`` or ``sprint``; the
team is paid ``PAY`` per worker plus ``synergy`` when both are busy, every worker receives that team reward, and each
worker's cost is its own ``STRAIN``. A worker observes ``t / horizon``. :func:`constrained_optimum` solves the occupancy
LP over the *joint* action, an upper bound for any pair of decentralised policies; with the budget ``d = horizon`` it is
both working every step (25), the greedy policy at every lambda in (0.5, 2.5)."""

from __future__ import annotations

import functools
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from scipy.optimize import linprog

from cmdp_rl.envs.multi_agent import ParallelEnv

AGENTS = ("worker_0", "worker_1")
ACTIONS = ("idle", "work", "sprint")
PAY = np.array([0.0, 1.0, 1.5])
STRAIN = np.array([0.0, 0.5, 1.5])


def joint_tables(synergy: float) -> tuple[np.ndarray, np.ndarray]:
    """Team reward ``[3, 3]`` and each agent's cost ``[2, 3, 3]`` of a joint action ``(a0, a1)``."""
    busy = (np.arange(3) > 0).astype(float)
    reward = PAY[:, None] + PAY[None, :] + synergy * np.outer(busy, busy)
    cost = np.stack([np.broadcast_to(STRAIN[:, None], (3, 3)), np.broadcast_to(STRAIN[None, :], (3, 3))])
    return reward, cost


def constrained_optimum(
    cost_limit: float | Sequence[float], horizon: int = 10, synergy: float = 0.5
) -> tuple[float, np.ndarray]:
    """The best expected team return within ``cost_limit`` (the team's budget, or one per agent) and the
    optimal joint action distribution ``[horizon, 3, 3]``: the LP over the occupancy of ``(t, a0, a1)``."""
    reward, cost = joint_tables(synergy)
    c = -np.tile(reward.reshape(-1), horizon)
    a_eq = np.kron(np.eye(horizon), np.ones((1, 9)))  # one unit of probability over the 9 joint actions a step
    if isinstance(cost_limit, (int, float)):
        a_ub, b_ub = np.tile(cost.sum(0).reshape(-1), horizon)[None, :], [float(cost_limit)]
    else:
        a_ub = np.stack([np.tile(cost[i].reshape(-1), horizon) for i in range(len(AGENTS))])
        b_ub = [float(d) for d in cost_limit]
    out = linprog(c, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=np.ones(horizon), bounds=(0, None), method="highs")
    if out.status != 0:
        raise ValueError(f"team work LP: {out.message}")
    return -out.fun, out.x.reshape(horizon, 3, 3)


class TeamWork(ParallelEnv):
    """The PettingZoo ``ParallelEnv`` of the module docstring."""

    metadata = {"name": "team_work_v0", "render_modes": []}
    possible_agents = list(AGENTS)
    cost_names = ("strain",)

    def __init__(self, horizon: int = 10, synergy: float = 0.5) -> None:
        self.horizon, self.synergy = horizon, synergy
        self.reward_table, self.cost_table = joint_tables(synergy)
        self.agents: list[str] = []
        self.t = 0

    @functools.lru_cache(maxsize=None)  # noqa: B019 - PettingZoo's idiom: the same space object each call
    def observation_space(self, agent: str) -> gym.Space:
        return gym.spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)

    @functools.lru_cache(maxsize=None)  # noqa: B019
    def action_space(self, agent: str) -> gym.Space:
        return gym.spaces.Discrete(len(ACTIONS))

    def _obs(self) -> dict[str, np.ndarray]:
        return {a: np.array([self.t / self.horizon], dtype=np.float32) for a in self.agents}

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        self.agents, self.t = list(AGENTS), 0
        return self._obs(), {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        a0, a1 = (int(actions[a]) for a in AGENTS)
        self.t += 1
        end = self.t >= self.horizon
        obs, agents = self._obs(), self.agents
        if end:
            self.agents = []
        team = float(self.reward_table[a0, a1])
        infos = {a: {"cost": float(self.cost_table[i, a0, a1])} for i, a in enumerate(agents)}
        return obs, {a: team for a in agents}, {a: end for a in agents}, {a: False for a in agents}, infos

    def state_dict(self) -> dict[str, Any]:
        return {"t": self.t, "agents": list(self.agents)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.t, self.agents = int(state["t"]), list(state["agents"])

    def close(self) -> None:
        pass

    @staticmethod
    def optimum(cost_limit: float | Sequence[float], horizon: int = 10, synergy: float = 0.5) -> float:
        """The exact constrained optimum (:func:`constrained_optimum`), which the end-of-run summary prints."""
        return constrained_optimum(cost_limit, horizon, synergy)[0]
