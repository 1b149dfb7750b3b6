"""A trained memoryless policy on the gridworld, valued exactly: its action probabilities in every
state, read off the network, then :func:`cmdp_rl.envs.grid.tabular.evaluate` (one linear solve). No
episodes, so no sampling noise: the optimality gap and each constraint's slack are exact for the
stochastic policy the network represents.

Only a policy that reads nothing but the one-hot observation (``policy=mlp`` without
``include_prev_action``/``include_prev_cost``) is a stationary table; a recurrent or windowed one
depends on its history and is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from cmdp_rl.envs.grid.optimum import ConstrainedOptimum
from cmdp_rl.envs.grid.tabular import GridCMDP, PolicyValue, TabularCMDP, evaluate
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys


@dataclass(frozen=True, eq=False)
class Optimum:
    """An optimal deterministic policy for one reward, and its exact values."""

    policy: np.ndarray  # [S, A] one-hot
    value: np.ndarray  # [S] optimal values of the reward optimised
    of_policy: PolicyValue  # the policy's return and costs on the CMDP's own r and c


def value_iteration(
    cmdp: TabularCMDP, reward: np.ndarray | None = None, tol: float = 1e-12, max_iterations: int = 1_000_000
) -> Optimum:
    """The optimum of the unconstrained MDP with ``reward`` (default ``cmdp.r``; pass e.g.
    ``-cmdp.c.sum(0)`` for the least-cost policy, or ``r - lambda . c`` for a Lagrangian) by value
    iteration to ``max |V_{n+1} - V_n| < tol``; the greedy policy is returned with its exact values."""
    rew = cmdp.r if reward is None else np.asarray(reward, dtype=np.float64)
    v = np.zeros(cmdp.num_states)
    for _ in range(max_iterations):
        q = rew + cmdp.gamma * cmdp.P @ v
        v_new = q.max(axis=1)
        done = np.max(np.abs(v_new - v)) < tol
        v = v_new
        if done:
            break
    else:
        raise RuntimeError(f"value iteration did not reach tol={tol} in {max_iterations} iterations")
    greedy = np.eye(cmdp.num_actions)[np.argmax(rew + cmdp.gamma * cmdp.P @ v, axis=1)]
    return Optimum(policy=greedy, value=v, of_policy=evaluate(cmdp, greedy))


def policy_table(agent: Agent, cmdp: GridCMDP) -> np.ndarray:
    """``pi[s, a]``: the agent's action probabilities on the one-hot observation of each state."""
    if agent.recurrent or set(agent.in_keys) - {keys.OBS, keys.IS_INIT}:
        raise ValueError(
            f"policy_table: the policy reads {agent.in_keys}, not the observation alone; "
            "only a memoryless policy is a table"
        )
    obs = torch.zeros(cmdp.num_states, cmdp.layout.num_cells)
    obs[torch.arange(cmdp.num_states), torch.as_tensor(cmdp.state_cells)] = 1.0
    with torch.no_grad():
        dist = agent.dist({keys.OBS: obs, keys.IS_INIT: torch.ones(cmdp.num_states, 1, dtype=torch.bool)})
    return dist.probs.double().numpy()


@dataclass(frozen=True)
class Gap:
    """A policy against the constrained optimum: exact return and costs, the relative gap
    ``(J* - J) / J*`` and whether every budget holds (to ``tol``)."""

    ret: float
    costs: tuple[float, ...]
    optimum: float
    budgets: tuple[float, ...]
    tol: float = 1e-9

    @property
    def gap(self) -> float:
        return (self.optimum - self.ret) / self.optimum

    @property
    def within_budgets(self) -> bool:
        return all(c <= d + self.tol for c, d in zip(self.costs, self.budgets))


def exact_gap(agent: Agent, cmdp: GridCMDP, best: ConstrainedOptimum) -> Gap:
    value: PolicyValue = evaluate(cmdp, policy_table(agent, cmdp))
    return Gap(
        float(value.ret), tuple(float(c) for c in value.costs), float(best.ret), tuple(float(d) for d in best.budgets)
    )
