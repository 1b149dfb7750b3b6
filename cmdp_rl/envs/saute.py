"""Sauté's env transform: the remaining safety budget joins the state and the reward is replaced once
the budget is spent: the safety augmented MDP of Sootla et al. (2022, "Sauté RL: Almost Surely Safe
Reinforcement Learning Using State Augmentation", ICML; docs/references.md).

The paper's safety state starts at the budget, ``z_0 = d``, and moves by ``z_{t+1} = (z_t - c_t) /
gamma_c`` (so ``z_t >= 0`` is ``sum_{k<t} gamma_c^k c_k <= d``); the policy sees ``(s_t, z_t)``, and
a step taken with the budget spent is worth a fixed penalty instead of the task's reward. Here ``z``
is normalised by ``d`` (``z_0 = 1``, as the paper's experiments feed it to the networks), one per
constraint (the reward is replaced when any is spent), and read *after* the step, so the step that
overspends is penalised itself (the pre-step reading would let it keep its reward). ``gamma_c = 1``,
``algo.budget_discount``'s default, counts this toolkit's budget, the undiscounted episode cost.
"""

from __future__ import annotations

from typing import Any, Sequence

import torch

from cmdp_rl.envs.vector import Step, VecEnv


class BudgetState:
    """The K normalised remaining budgets ``z`` of ``num_envs`` episodes (module docstring): the
    training env's and the video's (``video.py``) one count, so the policy sees the same state in both."""

    def __init__(
        self, budgets: Sequence[float], discount: float, num_envs: int, device: torch.device | str = "cpu"
    ) -> None:
        if min(budgets) <= 0:
            raise ValueError(f"budget state: one budget > 0 per cost needed, got {list(budgets)}")
        if not 0 < discount <= 1:
            raise ValueError(f"budget state: discount must be in (0, 1], got {discount}")
        self.budgets = torch.tensor(list(budgets), dtype=torch.float32, device=device).view(1, -1)
        self.discount = float(discount)
        self.z = self.full(num_envs)

    def full(self, num_envs: int | None = None) -> torch.Tensor:
        n = self.z.shape[0] if num_envs is None else num_envs
        return torch.ones(n, self.budgets.shape[1], dtype=torch.float32, device=self.budgets.device)

    def after(self, cost: torch.Tensor) -> torch.Tensor:
        """``z_{t+1} = (z_t - c_t / d) / gamma_c`` per constraint (z normalised by d)."""
        return (self.z - cost.to(self.z.dtype) / self.budgets) / self.discount

    @staticmethod
    def augment(obs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return torch.cat([obs, z.to(obs.dtype)], dim=-1)

    # the video's one-env path (video.py): the policy's observation, then the step's cost
    def start(self) -> None:
        self.z = self.full()

    def observation(self, obs: torch.Tensor) -> torch.Tensor:
        return self.augment(obs, self.z)

    def observe(self, cost: torch.Tensor) -> None:
        self.z = self.after(cost.view(self.z.shape))


class BudgetStateEnv(VecEnv):
    """``env`` with each observation followed by the K budgets ``z`` (``z = 1`` again in the
    observation after an episode's end) and, if ``reshape_reward``, every reward replaced by
    ``unsafe_reward`` on steps after which some ``z_k < 0``; everything else passes through."""

    def __init__(
        self,
        env: VecEnv,
        budgets: Sequence[float],
        discount: float = 1.0,
        unsafe_reward: float = 0.0,
        reshape_reward: bool = True,
    ) -> None:
        if len(budgets) != env.num_costs:
            raise ValueError(f"budget state: one budget > 0 per cost ({env.num_costs}) needed, got {list(budgets)}")
        self.state = BudgetState(budgets, discount, env.num_envs, env.device)
        self.wrap(env, obs_dim=env.obs_dim + env.num_costs)
        self.unsafe_reward, self.reshape_reward = float(unsafe_reward), reshape_reward

    @property
    def z(self) -> torch.Tensor:
        return self.state.z

    def reset(self, seed: int | None = None) -> torch.Tensor:
        obs = self.env.reset(seed=seed)
        self.state.start()
        return self.state.observation(obs)

    def step(self, action: torch.Tensor) -> Step:
        s = self.env.step(action)
        z_next = self.state.after(s.cost)
        reward = s.reward
        if self.reshape_reward:  # the reshaped objective: a spent budget earns the penalty
            spent = (z_next < 0).any(dim=-1, keepdim=True)
            reward = torch.where(spent, torch.full_like(reward, self.unsafe_reward), reward)
        done = s.terminated | s.truncated
        self.state.z = torch.where(done, self.state.full(), z_next)  # a new episode starts with the whole budget
        return s._replace(
            next_obs=self.state.augment(s.next_obs, z_next), reward=reward, obs=self.state.observation(s.obs)
        )

    def state_dict(self) -> dict[str, Any]:
        return {"env": self.env.state_dict(), "z": self.z.clone()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.env.load_state_dict(state["env"])
        self.state.z = state["z"].to(self.device).clone()
