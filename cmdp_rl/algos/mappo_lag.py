"""MAPPO-Lagrangian (``algo=mappo_lag``): constrained multi-agent PPO on ``env=pettingzoo``.

MAPPO (Yu et al., 2022, "The Surprising Effectiveness of PPO in Cooperative Multi-Agent Games") is
PPO with the agents' policy shared (parameter sharing, the agent's id among the actor's inputs) and
a centralised critic that values the state from every agent's observation. The constrained setting
is SafePO's MAPPO-L (Gu et al., 2023, "Safe Multi-Agent Reinforcement Learning for Multi-Robot
Control", and the Safe-Policy-Optimization benchmark): a Lagrangian multiplier per constraint, the
policy advantage ``(A_r - sum_k lambda_k A_c,k) / (1 + sum_k lambda_k)``.

Here the agents are rows of the batch (``envs/multi_agent.py``), so MAPPO needs no update of its
own: the PPO-Lagrangian update (``algos/ppo.py``) with its multipliers (``algos/multiplier.py``, the
shared machinery) runs on the rows, the MLP policy on a multi-agent env is the decentralised actor
over ``[own observation | agent id]`` and the critics read the whole row (every agent's
observation). What this module adds is the constraint's scope:

- ``constraint: team`` (default): one budget per cost on the team's cost, the sum over agents, one
  lambda per cost;
- ``constraint: per_agent``: a budget on each agent's cost, one lambda per agent and cost (the
  env's costs become ``<agent>/<cost>``; ``cost_limit`` one number for all, or a list of M * K).
"""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, ClassVar, Literal

from cmdp_rl.algos.multiplier import MultiplierConfig
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
    # The team task trains in 40 iterations, not hundreds: lambda must cross
    # the range a relative violation of about 2 gives in that time (0.5 on relative violations is the
    # raw step of 0.05 that the task was measured with, at its budget of 10).
    multiplier: MultiplierConfig = field(default_factory=lambda: MultiplierConfig(lr=0.5))
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
