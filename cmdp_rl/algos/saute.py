"""Sauté RL (Sootla et al., 2022, "Sauté RL: Almost Surely Safe Reinforcement Learning Using State
Augmentation", ICML): an unconstrained algorithm on the safety augmented MDP. The constraint goes into the
env (``envs/saute.py``: the remaining budget joins the state, the reward becomes ``unsafe_reward`` once it
is spent); this module declares that env (``wrap_env``; evaluation keeps the task's reward) and builds the
base algorithm from the options it shares with Sauté's. Its constraint is almost sure, stricter than a budget.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Annotated, Literal

from cmdp_rl.algos.base import Algorithm, per_constraint
from cmdp_rl.algos.ppo import PPOConfig
from cmdp_rl.config.registry import component, register
from cmdp_rl.config.validation import build, finite, options, require
from cmdp_rl.envs.saute import BudgetState, BudgetStateEnv
from cmdp_rl.envs.vector import VecEnv
from cmdp_rl.policies.agent import Agent

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig


@options
class SauteConfig(PPOConfig):
    """Sauté RL on a base algorithm (``base``), whose options are these (PPO's)."""

    name: str = "saute"
    # The algorithm trained on the augmented MDP, with the options it shares with these (PPO's).
    base: Literal["ppo"] = "ppo"
    unsafe_reward: Annotated[float, finite()] = -1.0  # the reward of a step taken with a budget spent
    # gamma_c of z's update (envs/saute.py); 1 counts the undiscounted episode cost that cost_limit budgets
    budget_discount: Annotated[float, finite(gt=0, le=1)] = 1.0

    def check(self, run: RunConfig) -> None:
        super().check(run)
        limits = self.cost_limit if isinstance(self.cost_limit, list) else [self.cost_limit]
        require(
            all(d > 0 for d in limits),
            "algo.cost_limit",
            "> 0 with algo=saute (the budget state is the remaining fraction of it)",
            self.cost_limit,
        )

    def wrap_env(self, env: VecEnv, evaluation: bool = False) -> VecEnv:
        """The safety augmented env: one budget state per cost; the reward reshaped for training."""
        budgets = per_constraint(self.cost_limit, "algo.cost_limit", env.cost_names)
        return BudgetStateEnv(env, budgets, self.budget_discount, self.unsafe_reward, reshape_reward=not evaluation)

    def observation_state(self, cost_names: tuple[str, ...]) -> BudgetState:
        """The budget state of one env, for paths that step a plain env (video.py)."""
        return BudgetState(per_constraint(self.cost_limit, "algo.cost_limit", cost_names), self.budget_discount, 1)


def make_saute(cfg: SauteConfig, agent: Agent) -> Algorithm:
    """The base algorithm, built from the options it shares with ``cfg``."""
    base = component("algo", cfg.base)
    shared = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(base.options) if f.name != "name"}
    return base.build(build(base.options, {**shared, "name": cfg.base}, "algo"), agent)


register("algo", "saute", SauteConfig, make_saute)
