"""The fork CMDP (``model.py``) as one tensor program over N envs (``env=fork``): each step looks up
every env's next state, reward and costs in the model's tables and draws one uniform number per env
for the random end, whether or not the episode could end there, so a seed fixes one stream whatever
the policy does; envs whose episode ended restart at the fork in the same step."""

from __future__ import annotations

import torch

from cmdp_rl.envs.fork.model import GOAL, ForkCMDP
from cmdp_rl.envs.vector import Step, VecEnv, table_actions, tabular


class TorchFork(VecEnv):
    """N forks in tensors. Observation: one-hot over the model's states and the goal (float32,
    ``[N, S + 1]``); action: one index in ``[0, 3)``; cost ``[N, K]`` named ``model.cost_names``."""

    saved = ("state", "generator")

    def __init__(self, model: ForkCMDP, num_envs: int, device: str | torch.device = "cpu") -> None:
        tabular(self, model, num_envs, device)
        self.model, self.obs_dim = model, model.obs_dim
        self.end_prob = 1.0 - model.gamma
        self.goal_index = model.num_states  # the goal's entry of the one-hot observation
        nxt = torch.as_tensor(model.next_state, device=self.device)
        self._next = torch.where(nxt == GOAL, torch.full_like(nxt, self.goal_index), nxt)  # [S, A]
        self._eye = torch.eye(model.obs_dim, device=self.device)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        if seed is not None:
            self.generator.manual_seed(seed)
        self.state = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)
        return self._eye[self.state]

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        self.state = self.state.masked_fill(rows, 0)
        return self._eye[self.state[rows]]

    def step(self, action: torch.Tensor) -> Step:
        a = table_actions(self, action, "fork")
        s = self.state
        nxt = self._next[s, a]
        at_goal = nxt == self.goal_index
        ends = torch.rand(self.num_envs, device=self.device, generator=self.generator) < self.end_prob
        terminated = at_goal | ends
        self.state = nxt.masked_fill(terminated, 0)
        return Step(
            next_obs=self._eye[nxt],
            reward=self._reward[s, a].unsqueeze(-1),
            cost=self._cost[s, a],
            terminated=terminated.unsqueeze(-1),
            truncated=torch.zeros_like(terminated).unsqueeze(-1),
            obs=self._eye[self.state],
        )
