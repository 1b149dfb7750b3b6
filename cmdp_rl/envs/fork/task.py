"""The fork as a component (``env=fork``): its options, checked before anything is built, the
batched env, and the exact constrained optimum the end-of-run summary compares with."""

from __future__ import annotations

from dataclasses import field
from typing import Annotated, ClassVar, Literal, Sequence

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import Field, PositiveFloat, PositiveInt, finite, options
from cmdp_rl.envs.fork.env import TorchFork
from cmdp_rl.envs.fork.model import DEFAULT_END_PROB, DEFAULT_GOAL_REWARD, DEFAULT_LENGTHS, ForkCMDP, fork_cmdp
from cmdp_rl.envs.grid.optimum import ConstrainedOptimum, solve_constrained
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.vector import VecEnv


@options
class ForkConfig(EnvOptions):
    """``env=fork``: three routes to a goal, K = 1 or 2 hazard costs (``model.py``)."""

    name: str = "fork"
    values_snapshots: ClassVar[bool] = True  # deploy.policy=auto (EnvOptions.values_snapshots)
    backend: Literal["torch"] = "torch"  # one tensor program over the envs (env.py), on `device`
    num_envs: PositiveInt = 16
    num_costs: Literal[1, 2] = 1  # 1: one cost, "hazard"; 2: "hazard_a" and "hazard_b", a budget each
    lengths: Annotated[
        list[PositiveInt], Field(min_length=3, max_length=3, description="three positive move counts, one per route")
    ] = field(default_factory=lambda: list(DEFAULT_LENGTHS))
    goal_reward: PositiveFloat = DEFAULT_GOAL_REWARD
    end_prob: Annotated[float, finite(gt=0, lt=1)] = DEFAULT_END_PROB

    def model(self) -> ForkCMDP:
        """The tabular CMDP these options describe."""
        return fork_cmdp(self.num_costs, self.lengths, self.goal_reward, self.end_prob)

    def solve(self, cost_limit: float | Sequence[float]) -> ConstrainedOptimum:
        """The exact constrained optimum at these budgets (one number: every constraint's)."""
        return solve_constrained(self.model(), cost_limit)

    def optimum(self, cost_limit: float | Sequence[float]) -> float:
        """The optimal expected episode return within the budgets, read by the end-of-run summary."""
        return self.solve(cost_limit).ret


def make_fork(cfg: ForkConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    return TorchFork(cfg.model(), num_envs, device=device)


register("env", "fork", ForkConfig, make_fork)
