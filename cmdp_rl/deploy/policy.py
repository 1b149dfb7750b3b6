"""The deployed policy as a user acts with it: ``cmdp_rl.load(run_dir).predict(obs)``, Stable-Baselines3's
``predict(observation, state, episode_start, deterministic) -> (action, state)``, carrying between calls what the
collector carries between steps; numpy or torch observations, ``[obs_dim]`` or ``[n, obs_dim]``, answered in kind."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import PolicyMemory


class DeployedPolicy:
    """``agent`` (holding the deployed actor) acting on an env with ``action_space`` and ``num_costs`` costs."""

    def __init__(self, agent: Agent, action_space: Any, num_costs: int, cfg: Any = None) -> None:
        self.agent, self.action_space, self.num_costs, self.cfg = agent.eval(), action_space, num_costs, cfg
        self.device = next(agent.parameters()).device

    @property
    def needs_cost(self) -> bool:
        """Whether the policy reads the previous step's cost (``policy.include_prev_cost``)."""
        return keys.PREV_COST in self.agent.in_keys

    @torch.no_grad()
    def predict(
        self,
        observation: Any,
        state: dict | None = None,
        episode_start: Any = None,
        deterministic: bool = True,
        cost: Any = None,
    ) -> tuple[np.ndarray, dict]:
        """The action and the state for the next call: ``state=None`` or ``episode_start`` (per env) start
        episodes; ``cost``: the previous action's costs, for a policy that reads them."""
        single = np.ndim(observation) == 1
        obs = torch.as_tensor(np.asarray(observation), dtype=torch.float32, device=self.device)
        obs = obs.unsqueeze(0) if single else obs
        n = obs.shape[0]
        if state is None:
            memory = PolicyMemory(self.agent, n, self.action_space, self.device, self.num_costs)
            state = {"memory": memory, "root": memory.start(), "is_init": torch.ones(n, 1, dtype=torch.bool)}
        elif state.get("out") is not None:
            memory = state["memory"]
            if memory.prev_cost and cost is None:
                raise ValueError("predict: this policy reads the previous step's cost: pass cost=[n, K] (or [K])")
            step_cost = torch.zeros(n, self.num_costs) if cost is None else torch.as_tensor(cost, dtype=torch.float32)
            starts = np.zeros(n, dtype=bool) if episode_start is None else np.asarray(episode_start)
            done = torch.as_tensor(starts, dtype=torch.bool).reshape(n, 1)
            _, carried = memory.step(state["out"], step_cost.reshape(n, self.num_costs).to(self.device), done)
            state = {**state, "root": {**state["root"], **carried}, "is_init": done}
        root = {**state["root"], keys.OBS: obs, keys.IS_INIT: state["is_init"].to(self.device)}
        out = self.agent.act(root, deterministic)
        action = out[keys.ACTION].cpu().numpy()
        if action.dtype.kind in "iu" and action.shape[-1:] == (1,):  # a Discrete index: one int per env
            action = action[..., 0]
        return (action[0] if single else action), {**state, "out": out}
