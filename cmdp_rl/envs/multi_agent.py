"""``env=pettingzoo env.factory=<module>:<callable>``: a PettingZoo ``ParallelEnv`` as a batched CMDP
(docs/multi_agent_and_hybrid.md).

N envs of M agents are ``N * M`` rows, row ``i * M + j`` agent ``j`` of env ``i``, so everything per row (collector,
GAE, critics, J_c) runs unchanged; an env's rows share its episode (it ends when any agent's does). A row's observation
is ``[own | one-hot agent id | every agent's]`` (a decentralised actor reads the first ``actor_obs_dim`` entries, the
critics all); its reward the agent's own; its cost, from each agent's ``info[agent]["cost"]``, the team's sum
(``constraint="team"``) or every agent's (``"per_agent"``, named ``<agent>/<cost>``). Every agent has the same action
space (one shared policy). Not SuperSuit: it drops ``info`` and resets agents independently."""

from __future__ import annotations

import importlib
from dataclasses import field
from typing import Annotated, Any, Callable, Literal

import numpy as np
import torch

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import ConfigError, Field, PositiveInt, options
from cmdp_rl.envs.contract import Checker, EnvContract, EnvContractError
from cmdp_rl.envs.env_state import env_state, load_env_state
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.vector import Step, VecEnv, default_cost_names
from cmdp_rl.rollout.actions import action_bounds, action_dim, check_action_space, to_env

Constraint = Literal["team", "per_agent"]

try:  # the registry imports every env module; PettingZoo is the multi_agent extra
    from pettingzoo import ParallelEnv
except ImportError:  # pragma: no cover - without the extra the class still has ParallelEnv's API
    ParallelEnv = object


def load_factory(spec: str) -> Callable[..., Any]:
    """``"module:callable"`` -> the callable, or a :class:`ConfigError` naming ``env.factory``."""
    module, sep, name = spec.partition(":")
    if not (module and sep and name):
        raise ConfigError(f"env.factory must be 'module:callable', got {spec!r}")
    try:
        found = getattr(importlib.import_module(module), name, None)
    except ImportError as exc:
        raise ConfigError(f"env.factory: cannot import {module!r}: {exc}") from exc
    if not callable(found):
        raise ConfigError(f"env.factory: {module!r} has no callable {name!r}")
    return found


def _flat(obs: Any, width: int) -> np.ndarray:
    flat = np.asarray(obs, dtype=np.float32).reshape(-1)
    return np.pad(flat, (0, width - flat.size))


def _cost(info: Any) -> np.ndarray:
    return np.asarray(info.get("cost", 0.0) if isinstance(info, dict) else 0.0, dtype=np.float32).reshape(-1)


def _row(batched: Any, r: int) -> Any:
    """Row ``r`` of what ``actions.to_env`` gives (an array, or a hybrid space's tuple or dict)."""
    if isinstance(batched, tuple):
        return tuple(b[r] for b in batched)
    if isinstance(batched, dict):
        return {k: v[r] for k, v in batched.items()}
    return batched[r]


class PettingZooVecEnv(VecEnv):
    """N parallel envs built by ``make_one``, their agents as rows (module docstring)."""

    def __init__(
        self,
        make_one: Callable[[], Any],
        num_envs: int,
        device: str | torch.device = "cpu",
        constraint: Constraint = "team",
        env_id: str = "pettingzoo",
    ) -> None:
        self.envs = [make_one() for _ in range(num_envs)]
        first = self.envs[0]
        self.agents = list(first.possible_agents)
        self.env_id, self.num_teams, self.device = env_id, num_envs, torch.device(device)
        m = self.num_agents = len(self.agents)
        self.num_envs = num_envs * m
        self.agents_per_env = m  # evaluation counts a team's episode once (evaluation.py)
        space = first.action_space(self.agents[0])
        for agent in self.agents[1:]:
            if first.action_space(agent) != space:
                raise ConfigError(
                    f"env {env_id}: agent {agent!r} has action space {first.action_space(agent)}, agent "
                    f"{self.agents[0]!r} {space}; a shared policy needs the same action space for every agent"
                )
        check_action_space(space, env_id)
        self._action_space = space
        self.action_dim = action_dim(space)
        low, high = action_bounds(space)
        self.action_low, self.action_high = low.to(self.device), high.to(self.device)
        self.width = max(int(np.prod(first.observation_space(a).shape)) for a in self.agents)
        self.actor_obs_dim = self.width + m
        self.obs_dim = self.actor_obs_dim + m * self.width
        self._ids = np.eye(m, dtype=np.float32)
        names = getattr(first, "cost_names", None)
        self.agent_cost_names = tuple(names) if names is not None else default_cost_names(self._probe_k(make_one))
        self.constraint = constraint

    def _probe_k(self, make_one: Callable[[], Any]) -> int:
        """K from one step of a throwaway instance (the training envs' generators stay untouched)."""
        env = make_one()
        try:
            env.reset(seed=0)
            actions = {a: env.action_space(a).sample() for a in env.agents}
            infos = env.step(actions)[4]
            return int(_cost(infos[self.agents[0]]).size) or 1
        except Exception:  # noqa: BLE001 - the contract check and the real steps report the real error
            return 1
        finally:
            env.close()

    @property
    def num_costs(self) -> int:
        return len(self.cost_names)

    @property
    def cost_names(self) -> tuple[str, ...]:
        if self.constraint == "team":
            return self.agent_cost_names
        return tuple(f"{a}/{c}" for a in self.agents for c in self.agent_cost_names)

    def _rows(self, obs: dict) -> np.ndarray:
        """One env's ``[M, obs_dim]`` rows from its agents' observations."""
        own = np.stack([_flat(obs[a], self.width) for a in self.agents])
        return np.concatenate([own, self._ids, np.broadcast_to(own.reshape(1, -1), (len(own), own.size))], axis=1)

    def _team_cost(self, infos: dict) -> np.ndarray:
        costs = np.stack([_cost(infos.get(a, {})) for a in self.agents])  # [M, K]
        row = costs.sum(0) if self.constraint == "team" else costs.reshape(-1)
        return np.broadcast_to(row, (self.num_agents, row.size))

    def _tensor(self, rows: list[np.ndarray]) -> torch.Tensor:
        return torch.from_numpy(np.concatenate(rows).astype(np.float32)).to(self.device)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        seeds = [None if seed is None else seed + i for i in range(self.num_teams)]
        return self._tensor([self._rows(env.reset(seed=s)[0]) for env, s in zip(self.envs, seeds)])

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        """A team's rows restart together (its agents share the episode): ``rows`` holds whole teams."""
        teams = rows.view(self.num_teams, self.num_agents).cpu()
        if bool((teams.any(1) != teams.all(1)).any()):
            raise ValueError("reset_rows: the rows of a team restart together; got part of a team")
        out = [self._rows(self.envs[i].reset()[0]) for i in torch.nonzero(teams.all(1)).view(-1).tolist()]
        return self._tensor(out) if out else torch.zeros(0, self.obs_dim, device=self.device)

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        sent = to_env(action, self._action_space)
        m = self.num_agents
        obs_rows, next_rows, rewards, costs, terms, truncs = [], [], [], [], [], []
        for i, env in enumerate(self.envs):
            actions = {a: _row(sent, i * m + j) for j, a in enumerate(self.agents)}
            obs, reward, terminated, truncated, infos = env.step(actions)
            term = any(bool(terminated.get(a, False)) for a in self.agents)
            done = term or any(bool(truncated.get(a, False)) for a in self.agents) or not env.agents
            next_rows.append(self._rows(obs))
            obs_rows.append(self._rows(env.reset()[0]) if done else next_rows[-1])
            rewards.append(np.array([float(reward.get(a, 0.0)) for a in self.agents], dtype=np.float32))
            costs.append(self._team_cost(infos))
            terms.append(np.full(m, term))
            truncs.append(np.full(m, done and not term))
        n = self.num_envs
        return Step(
            next_obs=self._tensor(next_rows),
            reward=self._tensor(rewards).view(n, 1),
            cost=self._tensor(costs).view(n, self.num_costs),
            terminated=torch.from_numpy(np.concatenate(terms)).view(n, 1).to(self.device),
            truncated=torch.from_numpy(np.concatenate(truncs)).view(n, 1).to(self.device),
            obs=self._tensor(obs_rows),
        )

    def check_contract(self, steps: int, seed: int, allow_negative_cost: bool, env_id: str | None) -> EnvContract:
        """``envs/contract.py``'s rules on each agent of each env (random actions, ``steps`` per env)."""
        name = env_id or self.env_id
        checks = {a: Checker(f"{name} agent {a!r}", None, allow_negative_cost) for a in self.agents}
        for index, env in enumerate(self.envs):
            obs, _ = env.reset(seed=seed + index)
            for t in range(steps + 1):
                if t > 0:
                    for j, a in enumerate(self.agents):
                        env.action_space(a).seed(seed + index * 1000 + t * 10 + j)
                    out = env.step({a: env.action_space(a).sample() for a in self.agents})
                    obs, reward, terminated, truncated, infos = out
                for a in self.agents:
                    where = (index, t)
                    if a not in obs:
                        checks[a].fail(where, "observation", f"is missing (agents observed: {sorted(obs)})")
                    checks[a].observation(where, obs[a], env.observation_space(a))
                    if t > 0:
                        checks[a].reward(where, reward.get(a))
                        checks[a].flag(where, "terminated", terminated.get(a))
                        checks[a].flag(where, "truncated", truncated.get(a))
                        checks[a].cost(where, infos.get(a))
                if t > 0 and (any(terminated.values()) or any(truncated.values()) or not env.agents):
                    obs, _ = env.reset()
        ks = {a: c.num_costs for a, c in checks.items()}
        if len(set(ks.values())) > 1:
            raise EnvContractError(f'env {name}: agents report different numbers of costs in info["cost"]: {ks}')
        return EnvContract(self.num_costs, self.cost_names)

    def state_dict(self) -> dict[str, Any]:
        return {"num_envs": self.num_teams, "envs": [_state(env) for env in self.envs]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["num_envs"] != self.num_teams:
            raise ValueError(f"env: saved state is for {state['num_envs']} envs, this one has {self.num_teams}")
        for env, saved in zip(self.envs, state["envs"]):
            env.load_state_dict(saved) if hasattr(env, "load_state_dict") else load_env_state(env, saved)

    def close(self) -> None:
        for env in self.envs:
            env.close()


def _state(env: Any) -> dict[str, Any]:
    return env.state_dict() if hasattr(env, "state_dict") else env_state(env)


@options
class PettingZooConfig(EnvOptions):
    """``env=pettingzoo``: ``factory(**kwargs)`` builds a ``ParallelEnv`` (``factory``: ``"module:callable"``)."""

    name: str = "pettingzoo"
    num_envs: PositiveInt = 8
    factory: Annotated[str, Field(pattern=r"^[\w.]+:\w+$", description="'module:callable'")] = (
        "cmdp_rl.envs.team_work:TeamWork"
    )
    kwargs: Annotated[dict, Field(description="a mapping of the factory's arguments")] = field(default_factory=dict)

    def env_id(self) -> str:
        return self.factory

    def make_one(self) -> Any:
        return load_factory(self.factory)(**self.kwargs)

    @property
    def optimum(self) -> Callable[[Any], float] | None:
        """The factory's exact constrained optimum (``<callable>.optimum(cost_limit, **kwargs)``), or None."""
        solver = getattr(load_factory(self.factory), "optimum", None)
        return None if solver is None else (lambda cost_limit: solver(cost_limit, **self.kwargs))


def make_pettingzoo(cfg: PettingZooConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    load_factory(cfg.factory)  # a bad factory is one line before any env is built
    return PettingZooVecEnv(cfg.make_one, num_envs, device=device, env_id=cfg.factory)


register("env", "pettingzoo", PettingZooConfig, make_pettingzoo)
