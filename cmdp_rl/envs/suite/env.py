"""A suite instance (``model.py``) as one tensor program over N envs (``env=suite``).

Each step looks up every env's reward and costs in the instance's tables, draws its next state
from ``P[s, a]`` by inverting the cumulative row with one uniform number, and ends the episode
after ``H`` steps, a true termination (time is part of the state); envs whose episode ended restart
(a start state drawn from ``mu0``) in the same step. Two uniform numbers per env per step, used or
not, so a seed fixes one stream whatever the policy does.

The observation is ``[one-hot(s), one-hot(t)]`` (S + H + 1 entries): the finite-horizon optimum is
not stationary, nor is "k steps left" for a critic. Side by side, an MLP's first layer computes
``W_s + W_t`` (what all steps share, learnt from every step), and a unit can pick out one (t, s).
"""

from __future__ import annotations

import torch

from cmdp_rl.envs.suite.model import FiniteCMDP
from cmdp_rl.envs.vector import Step, VecEnv, table_actions, tabular


class TorchSuite(VecEnv):
    """N copies of one suite instance in tensors: Discrete(A) actions, K costs ``cost_0..``."""

    saved = ("state", "t", "generator")

    def __init__(self, cmdp: FiniteCMDP, num_envs: int, device: str | torch.device = "cpu") -> None:
        tabular(self, cmdp, num_envs, device)
        self.cmdp, self.horizon, self.obs_dim = cmdp, cmdp.horizon, cmdp.num_states + cmdp.horizon + 1
        f64 = dict(dtype=torch.float64, device=self.device)
        # float64 cumulative rows, so that the sampled transitions are those of P to ~1e-16
        self._cdf = torch.as_tensor(cmdp.P, **f64).cumsum(-1)  # [S, A, S]
        self._cdf0 = torch.as_tensor(cmdp.mu0, **f64).cumsum(-1)  # [S]
        self._eye_s = torch.eye(cmdp.num_states, device=self.device)
        self._eye_t = torch.eye(cmdp.horizon + 1, device=self.device)
        self.t = torch.zeros(num_envs, dtype=torch.int64, device=self.device)

    def _obs(self, states: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
        return torch.cat([self._eye_s[states], self._eye_t[steps]], dim=-1)

    def _draw(self, cdf: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """The index each uniform ``u`` falls in along the cumulative rows ``cdf`` ``[N, S]`` (a
        row's last entry may fall short of 1 by rounding: clamp to the last state)."""
        return (u.unsqueeze(-1) >= cdf).sum(-1).clamp_(max=self.cmdp.num_states - 1)

    def _start(self, u: torch.Tensor) -> torch.Tensor:
        """Every row's initial state, drawn from mu0 with the uniforms ``u`` ``[N]``."""
        return self._draw(self._cdf0.expand(self.num_envs, -1), u)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        if seed is not None:
            self.generator.manual_seed(seed)
        u = torch.rand(self.num_envs, dtype=torch.float64, device=self.device, generator=self.generator)
        self.state = self._start(u)
        self.t = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)
        return self._obs(self.state, self.t)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        u = torch.rand(self.num_envs, dtype=torch.float64, device=self.device, generator=self.generator)
        self.state = torch.where(rows, self._start(u), self.state)
        self.t = self.t.masked_fill(rows, 0)
        return self._obs(self.state[rows], self.t[rows])

    def step(self, action: torch.Tensor) -> Step:
        a = table_actions(self, action, "suite")
        s = self.state
        u = torch.rand(2, self.num_envs, dtype=torch.float64, device=self.device, generator=self.generator)
        nxt = self._draw(self._cdf[s, a], u[0])
        t = self.t + 1
        terminated = t >= self.horizon
        start = self._start(u[1])
        self.state = torch.where(terminated, start, nxt)
        self.t = t.masked_fill(terminated, 0)
        return Step(
            next_obs=self._obs(nxt, t),
            reward=self._reward[s, a].unsqueeze(-1),
            cost=self._cost[s, a],
            terminated=terminated.unsqueeze(-1),
            truncated=torch.zeros_like(terminated).unsqueeze(-1),
            obs=self._obs(self.state, self.t),
        )
