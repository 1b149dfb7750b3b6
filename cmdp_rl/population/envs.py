"""A population's envs: each agent's N envs as rows ``[i N, (i + 1) N)`` of one env, seeded and budgeted as its
single run's (:func:`population_env`), one batched program where the env offers one (``EnvOptions.population_env``),
else each agent's own env stepped in turn (:class:`AgentEnvs`)."""

from __future__ import annotations

from typing import Any, Sequence

import torch

from cmdp_rl.algos.base import per_constraint
from cmdp_rl.envs import make_env, make_eval_env
from cmdp_rl.envs.early_termination import EarlyTerminated
from cmdp_rl.envs.saute import BudgetState
from cmdp_rl.envs.vector import Step, VecEnv


class AgentEnvs(VecEnv):
    """Each agent's own env, built and seeded as its single run's, stepped one after another: any
    batched env (K costs, a Discrete action), at P env steps per step where a population form takes one."""

    def __init__(self, envs: Sequence[VecEnv], seeds: Sequence[int]) -> None:
        self.envs, self.seeds = list(envs), [int(s) for s in seeds]
        self.rows = [e.num_envs for e in self.envs]
        self.num_envs = sum(self.rows)
        for k in ("num_costs", "obs_dim", "action_dim", "action_low", "action_high", "device"):
            setattr(self, k, getattr(self.envs[0], k))

    cost_names = property(lambda self: self.envs[0].cost_names)
    action_space = property(lambda self: self.envs[0].action_space)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        return torch.cat([e.reset(seed=s) for e, s in zip(self.envs, self.seeds)])

    def step(self, action: torch.Tensor) -> Step:
        steps = [e.step(a) for e, a in zip(self.envs, action.split(self.rows))]
        return Step(*(torch.cat(field) for field in zip(*steps)))

    def state_dict(self) -> dict[str, Any]:
        return {"envs": [e.state_dict() for e in self.envs]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for e, s in zip(self.envs, state["envs"]):
            e.load_state_dict(s)

    def close(self) -> None:
        for e in self.envs:
            e.close()


def population_env(
    cfgs: Sequence[Any], n: int, seeds: Sequence[int], device: torch.device, evaluation: bool = False
) -> VecEnv:
    """The agents' envs, ``n`` each, seeded per agent, as ``envs.make_env`` builds one agent's (``wrap_env``,
    the early-terminated MDP's cut in training) with each agent's own budgets."""
    env = cfgs[0].env.population_env([c.env for c in cfgs], n, seeds, device, evaluation)
    if env is None:
        if evaluation:
            return AgentEnvs([make_eval_env(c.env, n, device=device, algo=c.algo) for c in cfgs], seeds)
        cuts = [c.algo.cost_limit if c.early_terminate else None for c in cfgs]
        return AgentEnvs([make_env(c.env, n, device, c.algo, cut_at=d) for c, d in zip(cfgs, cuts)], seeds)
    budgets = [per_constraint(c.algo.cost_limit, "algo.cost_limit", env.cost_names) for c in cfgs]
    if cfgs[0].early_terminate and not evaluation:  # one option for all (no grid field)
        env = EarlyTerminated(env, torch.tensor(budgets, device=device).repeat_interleave(n, 0))
    wrapped = cfgs[0].algo.wrap_env(env, evaluation=evaluation)
    state = getattr(wrapped, "state", None)
    if isinstance(state, BudgetState):  # one row of budgets per env: its agent's
        state.budgets = torch.tensor(budgets, dtype=state.budgets.dtype, device=device).repeat_interleave(n, 0)
    return wrapped
