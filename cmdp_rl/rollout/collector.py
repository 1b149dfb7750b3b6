"""The one rollout collector every algorithm shares: it steps N envs (:class:`Envs`: an ``envs.VecEnv``) with an
agent (:class:`Acting`: a ``policies.agent.Agent``, or a population's ``PopulationAgent``) on plain tensors and returns one ``[num_envs, T]`` TensorDict in
torchrl's layout (``is_init``, ``"next"``, so torchrl's GAE reads it), reward and cost side by side under
``"next"``, with the running undiscounted episode sums on every step. Not torchrl's ``Collector``: it cost
more per step than stepping eight Reach1D envs (docs/guide/design.md).
"""

from __future__ import annotations

from typing import Any, Protocol, Sequence

import gymnasium as gym
import torch
from tensordict import TensorDict, TensorDictBase

from cmdp_rl.rollout import keys
from cmdp_rl.rollout.actions import action_dim, is_discrete, uniform_actions

Entries = dict  # key (a string, or a tuple for a nested key) -> tensor of one step, batch [N]


class Acting(Protocol):
    """What the collector and a policy's memory ask of an agent: ``policies.agent.Agent``, and P agents'
    ``population.stacked.PopulationAgent``."""

    @property
    def in_keys(self) -> list: ...

    def initial_state(self, num_envs: int, device: torch.device | str = "cpu") -> dict: ...

    def act(self, d: Entries, deterministic: bool = False) -> dict:
        """One step of N envs: the action, its log-prob and what the agent carries to the next step."""
        ...


class Envs(Protocol):
    """What the collector asks of the N envs it steps: ``envs.vector.VecEnv``'s interface (``step`` returns its
    ``Step``: next_obs, reward, cost, terminated, truncated, obs)."""

    num_envs: int
    num_costs: int
    device: Any

    @property
    def action_space(self) -> gym.Space: ...

    def reset(self, seed: int | None = None) -> torch.Tensor: ...

    def step(self, action: torch.Tensor) -> Any: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> None: ...


class PolicyMemory:
    """What a history-dependent agent carries between steps of N envs, as torchrl's env transforms would:
    its initial state, the state it returns under ``"next"`` (reset where an episode ended, as
    ``TensorDictPrimer`` does), and the previous action and cost if its ``in_keys`` ask. The collector's,
    the deployed policy's (``deploy.policy``) and the Reach1D replay's (``report.reach1d_episodes``)."""

    def __init__(
        self, agent: Acting, num_envs: int, action_space: gym.Space, device: torch.device, num_costs: int = 1
    ) -> None:
        self.initial = agent.initial_state(num_envs, device)
        in_keys = agent.in_keys
        self.prev_action = keys.PREV_ACTION in in_keys
        self.prev_cost = keys.PREV_COST in in_keys
        self.num_envs, self.device = num_envs, device
        self.num_costs = num_costs  # the previous cost is the whole vector of K costs
        # No previous action on an episode's first step: 0 for a box, -1 for discrete actions, an index no
        # action has (its one-hot encoding is all zeros).
        discrete, self.action_dim = is_discrete(action_space), action_dim(action_space)
        self.action_dtype, self.no_action = (torch.int64, -1) if discrete else (torch.float32, 0.0)

    def start(self) -> Entries:
        """The root entries of every env's first step (besides observation and ``is_init``)."""
        root = dict(self.initial)
        if self.prev_action:
            root[keys.PREV_ACTION] = torch.full(
                (self.num_envs, self.action_dim), self.no_action, dtype=self.action_dtype, device=self.device
            )
        if self.prev_cost:
            root[keys.PREV_COST] = torch.zeros(self.num_envs, self.num_costs, device=self.device)
        return root

    def step(self, out: Entries, cost: torch.Tensor, done: torch.Tensor) -> tuple[Entries, Entries]:
        """After a step: (the previous action/cost to store under ``"next"``: this step's; the root
        entries of the next step). ``out``: what the policy wrote; ``cost``: ``[N, K]``; ``done``: ``[N, 1]``."""
        carried = {k[1]: v for k, v in out.items() if isinstance(k, tuple) and k[0] == keys.NEXT}
        history = {}
        if self.prev_action:
            history[keys.PREV_ACTION] = out[keys.ACTION]
        if self.prev_cost:
            history[keys.PREV_COST] = cost
        if not (carried or history):
            return {}, {}
        # A new episode starts from the initial state, without history.
        root = {k: _reset_where(done, v, self.initial.get(k)) for k, v in carried.items()}
        if self.prev_action:
            root[keys.PREV_ACTION] = history[keys.PREV_ACTION].masked_fill(done, self.no_action)
        if self.prev_cost:
            root[keys.PREV_COST] = history[keys.PREV_COST].masked_fill(done, 0)
        return {(keys.NEXT, k): v for k, v in history.items()}, root


class Collector:
    """``rollout_steps`` steps of every env per :meth:`collect`, episodes running on across calls (one reset);
    ``deterministic``: the mode acts; the run's first ``uniform_steps`` env steps act uniformly at random."""

    def __init__(
        self,
        env: Envs,
        agent: Acting,
        rollout_steps: int,
        seed: int | None = None,
        deterministic: bool = False,
        uniform_steps: int = 0,
    ) -> None:
        self.env, self.agent, self.rollout_steps = env, agent, rollout_steps
        self.deterministic, self.uniform_steps = deterministic, uniform_steps
        n, dev = env.num_envs, env.device
        self._memory = PolicyMemory(agent, n, env.action_space, dev, env.num_costs)
        self._root: Entries = {
            **self._memory.start(),
            keys.OBS: env.reset(seed=seed),
            keys.IS_INIT: torch.ones(n, 1, dtype=torch.bool, device=dev),
        }
        self._ep_return = torch.zeros(n, 1, device=dev)
        self._ep_cost = torch.zeros(n, env.num_costs, device=dev)  # one running sum per constraint
        self._ep_length = torch.zeros(n, 1, dtype=torch.int64, device=dev)
        self.total_steps = 0
        self.total_costs = [0.0] * env.num_costs

    @torch.no_grad()
    def collect(self) -> TensorDictBase:
        steps: list[Entries] = []
        root = self._root
        ep_return, ep_cost, ep_length = self._ep_return, self._ep_cost, self._ep_length
        for t in range(self.rollout_steps):
            out = self.agent.act(root, self.deterministic)
            if self.total_steps + t * self.env.num_envs < self.uniform_steps:
                out[keys.ACTION], out[keys.LOG_PROB] = uniform_actions(
                    self.env.action_space, self.env.num_envs, self.env.device
                )
            step = self.env.step(out[keys.ACTION])
            done = step.terminated | step.truncated
            ep_return = ep_return + step.reward
            ep_cost = ep_cost + step.cost
            ep_length = ep_length + 1
            history, carried = self._memory.step(out, step.cost, done)
            steps.append(
                {
                    **root,
                    **out,
                    **history,
                    (keys.NEXT, keys.OBS): step.next_obs,
                    (keys.NEXT, keys.REWARD): step.reward,
                    (keys.NEXT, keys.COST): step.cost,
                    (keys.NEXT, keys.TERMINATED): step.terminated,
                    (keys.NEXT, keys.TRUNCATED): step.truncated,
                    (keys.NEXT, keys.DONE): done,
                    (keys.NEXT, keys.EPISODE_RETURN): ep_return,
                    (keys.NEXT, keys.EPISODE_COST): ep_cost,
                    (keys.NEXT, keys.EPISODE_LENGTH): ep_length,
                }
            )
            ep_return = ep_return.masked_fill(done, 0.0)
            ep_cost = ep_cost.masked_fill(done, 0.0)
            ep_length = ep_length.masked_fill(done, 0)
            root = {**carried, keys.OBS: step.obs, keys.IS_INIT: done}
        self._root = root
        self._ep_return, self._ep_cost, self._ep_length = ep_return, ep_cost, ep_length
        self.total_steps += self.rollout_steps * self.env.num_envs
        n = self.env.num_envs
        batch = TensorDict(
            {k: torch.stack([s[k] for s in steps], dim=1) for k in steps[0]},
            batch_size=[n, self.rollout_steps],
            device=self.env.device,
        )
        cost = batch.get((keys.NEXT, keys.COST))
        # K = 1 sums the whole batch in one reduction (same rounding as a scalar cost).
        sums = [cost.sum().item()] if cost.shape[-1] == 1 else cost.sum((0, 1)).tolist()
        self.total_costs = [t + s for t, s in zip(self.total_costs, sums)]
        return batch

    @property
    def total_cost(self) -> float:
        """Every cost collected so far (one constraint); :attr:`total_costs` has one per constraint."""
        if len(self.total_costs) != 1:
            raise ValueError(f"total_cost: the env has {len(self.total_costs)} costs; read total_costs")
        return self.total_costs[0]

    def state_dict(self) -> dict[str, Any]:
        """Where the rollout stands: a collector built anew and given this continues the same trajectories."""
        return {
            "root": dict(self._root),
            "episode_return": self._ep_return.clone(),
            "episode_cost": self._ep_cost.clone(),
            "episode_length": self._ep_length.clone(),
            "total_steps": self.total_steps,
            "total_cost": self.total_costs[0] if len(self.total_costs) == 1 else list(self.total_costs),
            "env": self.env.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.env.load_state_dict(state["env"])
        dev = self.env.device
        self._root = {k: v.to(dev) for k, v in state["root"].items()}
        self._ep_return = state["episode_return"].to(dev).clone()
        self._ep_cost = state["episode_cost"].to(dev).clone()
        self._ep_length = state["episode_length"].to(dev).clone()
        self.total_steps = int(state["total_steps"])
        total = state["total_cost"]
        self.total_costs = [float(t) for t in total] if isinstance(total, (list, tuple)) else [float(total)]


def _reset_where(done: torch.Tensor, value: torch.Tensor, initial: torch.Tensor | None) -> torch.Tensor:
    """``value`` with the rows of envs whose episode ended (``done``: ``[N, 1]``) set to ``initial``."""
    where = done.view(done.shape[0], *([1] * (value.dim() - 1)))
    return torch.where(where, torch.zeros_like(value) if initial is None else initial, value)


def finished_episodes(batch: TensorDictBase) -> dict[str, torch.Tensor]:
    """Return ``[E]``, cost ``[E, K]`` and length ``[E]`` of every episode that ended inside ``batch``."""
    done = batch.get((keys.NEXT, keys.DONE)).squeeze(-1)
    nxt = batch.get(keys.NEXT)
    return {
        "return": nxt.get(keys.EPISODE_RETURN).squeeze(-1)[done].float(),
        "cost": nxt.get(keys.EPISODE_COST)[done].float(),
        "length": nxt.get(keys.EPISODE_LENGTH).squeeze(-1)[done].float(),
    }


def episode_rows(collector: Collector, quota: Sequence[int]) -> list[list[tuple[float, ...]]]:
    """Env i's first ``quota[i]`` whole episodes from ``collector``, each as (return, length,
    terminated, cost_0, ..., cost_{K-1})."""
    rows: list[list[tuple[float, ...]]] = [[] for _ in quota]
    while any(len(r) < q for r, q in zip(rows, quota)):
        batch = collector.collect()
        nxt = batch.get(keys.NEXT)
        done = nxt.get(keys.DONE).squeeze(-1)
        for i, t in done.nonzero().tolist():
            if len(rows[i]) < quota[i]:
                rows[i].append(
                    (
                        nxt.get(keys.EPISODE_RETURN)[i, t, 0].item(),
                        float(nxt.get(keys.EPISODE_LENGTH)[i, t, 0].item()),
                        float(nxt.get(keys.TERMINATED)[i, t, 0].item()),
                        *nxt.get(keys.EPISODE_COST)[i, t].tolist(),
                    )
                )
    return rows
