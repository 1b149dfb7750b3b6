"""MAPPO-Lagrangian on ``env=pettingzoo``: MAPPO (Yu et al., 2022, "The Surprising Effectiveness of PPO in
Cooperative Multi-Agent Games": a shared actor with the agent's id among its inputs, centralised critics)
with SafePO's MAPPO-L multipliers (Gu et al., 2023). The agents are rows of the batch (envs/multi_agent.py),
so the update is PPO-Lagrangian's; this module adds the constraint's scope: ``team``, a budget per cost on
the agents' sum; ``per_agent``, one per agent and cost (costs ``<agent>/<cost>``).
"""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, ClassVar, Literal

from cmdp_rl.algos.multiplier_options import AdvantageScale, DualOptions, MultiplierConfig
from cmdp_rl.algos.ppo_lag import PPOLagConfig, PPOLagrangian
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import options, require

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig
    from cmdp_rl.envs.vector import VecEnv


@options
class MAPPOLagConfig(PPOLagConfig):
    """PPO-Lagrangian's options, and the constraint's scope (module docstring)."""

    name: str = "mappo_lag"
    constraint: Literal["team", "per_agent"] = "team"
    # 0.5 on relative violations: the raw step of 0.05 the 40-iteration team task was measured with (d = 10).
    multiplier: MultiplierConfig = field(default_factory=lambda: DualOptions(lr=0.5))
    advantage_scale: AdvantageScale = "raw"  # as measured on the team task
    envs: ClassVar[tuple[str, ...]] = ("pettingzoo",)  # its agents are the rows of that env's batch
    tiny_env: ClassVar[dict] = {"name": "pettingzoo", "num_envs": 1}  # two agents: 2 rows, as TINY's 2 envs

    def check(self, run: RunConfig) -> None:
        super().check(run)
        require(
            run.policy.name == "mlp",
            "policy.name",
            "mlp with algo=mappo_lag (the decentralised actor and centralised critic)",
            run.policy.name,
        )

    def wrap_env(self, env: VecEnv, evaluation: bool = False) -> VecEnv:
        """The env with the costs this scope budgets: the team's sum, or each agent's."""
        env.constraint = self.constraint
        return env


register("algo", "mappo_lag", MAPPOLagConfig, PPOLagrangian)

__all__ = ["MAPPOLagConfig"]
