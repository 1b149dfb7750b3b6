"""Hold each chosen skill for ``k`` steps: the seed's ``pi = pi_hi o pi_lo`` with two time scales.

:class:`HeldSkill` wraps a batched env whose actions are hybrid (``[skill, params...]``,
``cmdp_rl.rollout.actions.hybrid``). On a decision step (an episode's first step, then every
``k``-th) the skill the policy emits is taken and held; on the ``k - 1`` steps after it the env steps
with the held skill whatever the policy emits, and the policy's parameters every step. The
observation gains a one-hot of the held skill and the hold's phase ``j / k`` (both 0 on a decision
step). How the held steps are credited: docs/multi_agent_and_hybrid.md.
"""

from __future__ import annotations

import torch

from cmdp_rl.envs.vector import Step, VecEnv
from cmdp_rl.rollout.actions import hybrid


class HeldSkill(VecEnv):
    """``env`` with each skill held for ``k`` steps (module docstring)."""

    saved = ("env", "held", "phase")

    def __init__(self, env: VecEnv, k: int) -> None:
        parts = hybrid(env.action_space)
        if parts is None:
            raise ValueError(f"hold: the env's action space {env.action_space} is not a hybrid skill space")
        self.k, self.skills = k, parts.skills
        self.wrap(env, obs_dim=env.obs_dim + parts.skills + 1)
        self.held = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)
        self.phase = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)

    def _obs(self, obs: torch.Tensor, held: torch.Tensor, phase: torch.Tensor) -> torch.Tensor:
        onehot = torch.nn.functional.one_hot(held, self.skills).float() * (phase > 0).unsqueeze(-1)
        return torch.cat([obs, onehot, (phase.float() / self.k).unsqueeze(-1)], dim=-1)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        self.held.zero_()
        self.phase.zero_()
        return self._obs(self.env.reset(seed), self.held, self.phase)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        self.held = self.held.masked_fill(rows, 0)
        self.phase = self.phase.masked_fill(rows, 0)
        return self._obs(self.env.reset_rows(rows), self.held[rows], self.phase[rows])

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        decide = self.phase == 0
        skill = torch.where(decide, action[:, 0].round().long(), self.held)
        action = torch.cat([skill.unsqueeze(-1).to(action.dtype), action[:, 1:]], dim=-1)
        step = self.env.step(action)
        done = (step.terminated | step.truncated).squeeze(-1)
        phase = (self.phase + 1) % self.k
        # The final observation shows the hold as it stood after the step; the reset one a fresh start.
        next_obs = self._obs(step.next_obs, skill, phase)
        self.held = skill.masked_fill(done, 0)
        self.phase = phase.masked_fill(done, 0)
        return step._replace(next_obs=next_obs, obs=self._obs(step.obs, self.held, self.phase))
