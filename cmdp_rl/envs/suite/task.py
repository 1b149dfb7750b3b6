"""The generated suite as a component (``env=suite``, ``env.instance=<i>``): its options, the batched
env, the instance's budgets as the task's, and the exact constrained optimum the end-of-run summary
compares with."""

from __future__ import annotations

from typing import Literal, Sequence

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import NonNegativeInt, PositiveInt, options
from cmdp_rl.envs.grid.optimum import ConstrainedOptimum
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.suite.env import TorchSuite
from cmdp_rl.envs.suite.model import FiniteCMDP, generate, solve
from cmdp_rl.envs.vector import VecEnv


@options
class SuiteConfig(EnvOptions):
    """``env=suite``: instance ``instance`` of the generated finite-horizon CMDPs (``model.py``)."""

    name: str = "suite"
    backend: Literal["torch"] = "torch"  # one tensor program over the envs (env.py), on `device`
    num_envs: PositiveInt = 16
    instance: NonNegativeInt = 0

    def model(self) -> FiniteCMDP:
        """The instance's arrays (generated once per process and instance)."""
        return generate(self.instance)

    def episode_steps(self) -> int:
        """Every episode lasts the instance's horizon (what sizes the snapshot valuation's episodes)."""
        return self.model().horizon

    def budget(self) -> float | list[float]:
        """The instance's budgets: one number where it has one cost, else one per cost."""
        d = [float(x) for x in self.model().budgets]
        return d[0] if len(d) == 1 else d

    def solve(self, cost_limit: float | Sequence[float] | None = None) -> ConstrainedOptimum:
        """The exact constrained optimum at these budgets (None: the instance's), ``model.solve``."""
        return solve(self.model(), cost_limit)

    def optimum(self, cost_limit: float | Sequence[float]) -> float:
        """The optimal expected episode return within the budgets, read by the end-of-run summary."""
        return self.solve(cost_limit).ret


def make_suite(cfg: SuiteConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    return TorchSuite(cfg.model(), num_envs, device=device)


register("env", "suite", SuiteConfig, make_suite)
