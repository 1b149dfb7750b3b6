"""Safety-Gymnasium's multi-agent velocity tasks (Safety-MaMuJoCo) as a factory for ``env=pettingzoo``:

    python train.py env=pettingzoo env.factory=cmdp_rl.envs.safety_gym.multi_agent:SafetyMaMuJoCo \\
        +env.kwargs.scenario=HalfCheetah +env.kwargs.agent_conf=2x3 algo=mappo_lag algo.constraint=per_agent

Each agent's cost goes to ``infos[agent]["cost"]``. ``make_ma`` gets the unwrapped ``<scenario>-v5`` and
the time limit is kept here: gymnasium 1.x's ``TimeLimit`` no longer forwards the attributes
``SafeMAEnv`` reads. Every agent receives the same velocity cost, so ``algo.constraint=team`` sums M
copies of it; ``per_agent`` budgets each agent's copy (SafePO's MAPPO-L)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from cmdp_rl.envs.env_state import env_state, load_env_state
from cmdp_rl.envs.multi_agent import ParallelEnv
from cmdp_rl.envs.safety_gym.compat import import_safety_gymnasium


class SafetyMaMuJoCo(ParallelEnv):
    """``safety_gymnasium.make_ma(scenario, agent_conf)`` with each agent's cost in its info."""

    metadata = {"name": "safety_mamujoco", "render_modes": []}
    cost_names = ("velocity",)

    def __init__(
        self, scenario: str = "HalfCheetah", agent_conf: str = "2x3", max_steps: int = 1000, agent_obsk: int = 1
    ) -> None:
        safety_gymnasium = import_safety_gymnasium()
        self.base = gym.make(f"{scenario}-v5").unwrapped
        self.env = safety_gymnasium.make_ma(scenario, agent_conf, agent_obsk=agent_obsk, gym_env=self.base)
        self.possible_agents = list(self.env.possible_agents)
        self.max_steps = max_steps
        self.agents: list[str] = []
        self.t = 0

    def observation_space(self, agent: str) -> gym.Space:
        return self.env.observation_space(agent)

    def action_space(self, agent: str) -> gym.Space:
        return self.env.action_space(agent)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        self.agents, self.t = list(self.possible_agents), 0
        return self.env.reset(seed=seed, options=options)

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        obs, rewards, costs, terminations, truncations, infos = self.env.step(actions)
        self.t += 1
        infos = {a: {**infos.get(a, {}), "cost": float(costs[a])} for a in self.agents}
        if self.t >= self.max_steps:
            truncations = {a: True for a in self.agents}
        if any(terminations.values()) or any(truncations.values()):
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    def state_dict(self) -> dict[str, Any]:
        """The step count and the MuJoCo env's whole state (``envs/env_state.py``)."""
        return {"t": self.t, "agents": list(self.agents), "base": env_state(self.base)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.t, self.agents = int(state["t"]), list(state["agents"])
        load_env_state(self.base, state["base"])

    def close(self) -> None:
        self.env.close()
