"""The early-terminated MDP: a training episode ends at the first step after which its cost passes the
budget (Sun et al., 2021, "Safe Exploration by Solving Early Terminated MDP", arXiv 2107.04200), so
its plain return already pays for a violation. The cut is a termination (no bootstrap after it), when
*any* constraint's undiscounted episode sum exceeds its budget d strictly (a sum at d is within
budget, as the evaluation's verdict counts it); training envs only (``envs.make_env``'s ``cut_at``).
Why, and what it does with each algorithm and env: docs/constraint_satisfaction.md.
"""

from __future__ import annotations

from typing import Any, Sequence

import torch

from cmdp_rl.config.validation import ConfigError
from cmdp_rl.envs.vector import Step, VecEnv


class EarlyTerminated(VecEnv):
    """``env`` cut at its budgets (module docstring): ``[K]``, or ``[N, K]`` (a row's own, as a
    population's agents have). The cut rows restart through ``env.reset_rows``."""

    saved = ("env", "spent")

    def __init__(self, env: VecEnv, budgets: Sequence[float] | torch.Tensor) -> None:
        if type(env).reset_rows is VecEnv.reset_rows:
            raise ConfigError(
                f"early_terminate: true needs an env that can restart single episodes (VecEnv.reset_rows); "
                f"{type(env).__name__} has none: false, or give it one"
            )
        self.wrap(env)
        b = torch.as_tensor(budgets, dtype=torch.float32, device=self.device)
        self.budgets = b.view(1, -1) if b.dim() == 1 else b
        self.spent = torch.zeros(self.num_envs, self.num_costs, device=self.device)  # running episode costs

    def __getattr__(self, name: str) -> Any:
        # What an env declares besides the VecEnv interface (a team env's agents_per_env) is the wrapped env's.
        return getattr(self.env, name)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        self.spent = torch.zeros_like(self.spent)
        return self.env.reset(seed)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        self.spent = self.spent.masked_fill(rows.view(-1, 1), 0.0)
        return self.env.reset_rows(rows)

    def step(self, action: torch.Tensor) -> Step:
        s = self.env.step(action)
        spent = self.spent + s.cost.to(self.spent.dtype)
        over = (spent > self.budgets).any(dim=-1, keepdim=True)
        ended = s.terminated | s.truncated
        cut = over & ~ended  # rows the env did not end itself: restart them here
        obs = s.obs
        if bool(cut.any()):
            obs = obs.clone()
            rows = cut.squeeze(-1)
            obs[rows] = self.env.reset_rows(rows).to(obs.dtype)
        self.spent = spent.masked_fill(ended | over, 0.0)
        terminated = s.terminated | over
        # A step that both times out and passes the budget ends by the budget: no bootstrap.
        return s._replace(terminated=terminated, truncated=s.truncated & ~terminated, obs=obs)
