"""The fork CMDP (``model.py``) as one tensor program over N envs (``env=fork``): each step looks up
every env's next state, reward and costs in the model's tables and draws one uniform number per env
for the random end, whether or not the episode could end there, so a seed fixes one stream whatever
the policy does; envs whose episode ended restart at the fork in the same step."""

from __future__ import annotations

import gymnasium as gym
import torch

from cmdp_rl.envs.fork.model import GOAL, NUM_ACTIONS, ForkCMDP
from cmdp_rl.envs.vector import Step, VecEnv


class TorchFork(VecEnv):
    """N forks in tensors. Observation: one-hot over the model's states and the goal (float32,
    ``[N, S + 1]``); action: one index in ``[0, 3)``; cost ``[N, K]`` named ``model.cost_names``."""

    saved = ("state", "generator")

    def __init__(self, model: ForkCMDP, num_envs: int, device: str | torch.device = "cpu") -> None:
        self.model = model
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.num_costs = model.num_costs
        self.obs_dim = model.obs_dim
        self.action_dim = 1
        self.action_low = torch.zeros(1, device=self.device)
        self.action_high = torch.full((1,), NUM_ACTIONS - 1.0, device=self.device)
        self._cost_names, self._action_space = model.cost_names, gym.spaces.Discrete(NUM_ACTIONS)
        self.end_prob = 1.0 - model.gamma
        goal_index = model.num_states  # the goal's entry of the one-hot observation
        nxt = torch.as_tensor(model.next_state, device=self.device)
        self._next = torch.where(nxt == GOAL, torch.full_like(nxt, goal_index), nxt)  # [S, A]
        self._reward = torch.as_tensor(model.r, dtype=torch.float32, device=self.device)  # [S, A]
        self._cost = torch.as_tensor(model.c, dtype=torch.float32, device=self.device).permute(1, 2, 0)  # [S, A, K]
        self._eye = torch.eye(model.obs_dim, device=self.device)
        self.goal_index = goal_index
        self.generator = torch.Generator(device=self.device)
        self.state = torch.zeros(num_envs, dtype=torch.int64, device=self.device)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        if seed is not None:
            self.generator.manual_seed(seed)
        self.state = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)
        return self._eye[self.state]

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        self.state = self.state.masked_fill(rows, 0)
        return self._eye[self.state[rows]]

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        a = action[:, 0].to(device=self.device, dtype=torch.int64)
        if bool(((a < 0) | (a >= NUM_ACTIONS)).any()):
            raise ValueError(f"fork action must be in 0..{NUM_ACTIONS - 1}, got {action.flatten().tolist()}")
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
