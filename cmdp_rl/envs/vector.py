"""The batched env interface the collector drives, tensors in and tensors out (torchrl's env machinery
would cost more than the envs' steps: docs/guide/design.md), and its gymnasium implementation."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Callable, NamedTuple, Sequence

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AsyncVectorEnv, AutoresetMode, SyncVectorEnv

from cmdp_rl.config.validation import ConfigError
from cmdp_rl.envs.env_state import env_state, load_env_state
from cmdp_rl.rollout.actions import action_bounds, action_dim, check_action_space, to_env


class Step(NamedTuple):
    """One step of N envs. ``next_obs`` is what the step led to (the final observation where an
    episode ended, needed to bootstrap a truncated one); ``obs`` is what the agent acts on next
    (the reset observation where an episode ended). Reward and flags are ``[N, 1]``; cost is
    ``[N, K]``, one column per constraint (K = 1: an env reporting one number)."""

    next_obs: torch.Tensor
    reward: torch.Tensor
    cost: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor
    obs: torch.Tensor


def default_cost_names(num_costs: int) -> tuple[str, ...]:
    """The names of K costs an env does not name: ``cost_0 ... cost_{K-1}``."""
    return tuple(f"cost_{k}" for k in range(num_costs))


class VecEnv(ABC):
    """N environments stepped together, with per-env auto-reset. ``num_costs`` (K) costs per step,
    named ``cost_names`` (the env's names, else :func:`default_cost_names`).

    A wrapper (Sauté's budget state, the held skill, the early-terminated MDP) keeps the env it wraps
    as ``env`` (:meth:`wrap`): its cost names, action space and ``close`` are that env's. ``saved``
    names the attributes a resume restores (:meth:`state_dict`): tensors, torch generators, objects
    with a ``state_dict`` (a wrapper's ``env``)."""

    num_envs: int
    num_costs: int = 1
    obs_dim: int
    action_dim: int
    action_low: torch.Tensor
    action_high: torch.Tensor
    device: torch.device
    env: VecEnv | None = None
    saved: tuple[str, ...] = ()
    # What an env declares instead of the defaults below: its cost names, its action space.
    _cost_names: tuple[str, ...] = ()
    _action_space: gym.Space | None = None

    @abstractmethod
    def reset(self, seed: int | None = None) -> torch.Tensor:
        """Reset every env; returns observations ``[N, obs_dim]``."""

    @abstractmethod
    def step(self, action: torch.Tensor) -> Step:
        """Apply ``action`` ``[N, action_dim]``; envs whose episode ended are reset."""

    def wrap(self, env: VecEnv, obs_dim: int | None = None) -> None:
        """Wrap ``env``: take its interface, with ``obs_dim`` where the wrapper adds to the observation."""
        self.env, self.num_envs, self.num_costs, self.device = env, env.num_envs, env.num_costs, env.device
        self.obs_dim = env.obs_dim if obs_dim is None else obs_dim
        self.action_dim, self.action_low, self.action_high = env.action_dim, env.action_low, env.action_high
        self._cost_names, self._action_space = env.cost_names, env.action_space

    @property
    def cost_names(self) -> tuple[str, ...]:
        return self._cost_names or default_cost_names(self.num_costs)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        """Start a new episode in each env where ``rows`` (``[N]`` bool) is set, between steps, as the
        env's own auto-reset would; returns their first observations ``[R, obs_dim]``, in row order.
        Optional: the early-terminated MDP (``envs/early_termination.py``) needs it to cut an episode."""
        raise NotImplementedError(f"{type(self).__name__} cannot restart single episodes")

    def close(self) -> None:
        if self.env is not None:
            self.env.close()

    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs to continue exactly where this env stands (episodes in
        progress, random generators), for ``load_state_dict`` on a fresh env of the same config."""
        if not self.saved:
            raise NotImplementedError(f"{type(self).__name__} cannot save its state, so a run on it cannot resume")
        return {"num_envs": self.num_envs, **{name: _saved(getattr(self, name)) for name in self.saved}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if not self.saved:
            raise NotImplementedError(f"{type(self).__name__} cannot restore a saved state")
        if state.get("num_envs", self.num_envs) != self.num_envs:
            raise ValueError(f"env: saved state is for {state['num_envs']} envs, this one has {self.num_envs}")
        for name in self.saved:
            value = getattr(self, name)
            if isinstance(value, torch.Tensor):
                setattr(self, name, state[name].to(self.device).clone())
            elif isinstance(value, torch.Generator):
                value.set_state(state[name])
            else:
                value.load_state_dict(state[name])

    @property
    def action_space(self) -> gym.Space:
        """One env's action space, which the agent's action distribution is chosen from
        (``policies/distributions.py``): the box ``[action_low, action_high]`` unless the env says
        otherwise."""
        if self._action_space is not None:
            return self._action_space
        return gym.spaces.Box(self.action_low.cpu().numpy(), self.action_high.cpu().numpy(), dtype=np.float32)

    def check_action(self, action: torch.Tensor) -> None:
        expected = (self.num_envs, self.action_dim)
        if tuple(action.shape) != expected:
            raise ValueError(f"action: expected shape {expected} (num_envs, action_dim), got {tuple(action.shape)}")


def _saved(value: Any) -> Any:
    """One of ``VecEnv.saved``'s attributes as a checkpoint holds it."""
    if isinstance(value, torch.Tensor):
        return value.clone()
    if isinstance(value, torch.Generator):
        return value.get_state()
    if not hasattr(value, "state_dict"):
        raise NotImplementedError(f"{type(value).__name__} cannot save its state")
    return value.state_dict()


def tabular(env: VecEnv, model: Any, num_envs: int, device: str | torch.device) -> None:
    """Set ``env`` up as N batched copies of a tabular ``model`` (the suite's, the fork's): one action,
    an index of ``Discrete(A)``; K costs named ``model.cost_names``; the reward ``[S, A]`` and costs
    ``[S, A, K]`` as float32 tables; a generator; every env in state 0."""
    env.num_envs, env.device, env.num_costs, env.action_dim = num_envs, torch.device(device), model.num_costs, 1
    env.action_low = torch.zeros(1, device=env.device)
    env.action_high = torch.full((1,), model.num_actions - 1.0, device=env.device)
    env._cost_names, env._action_space = model.cost_names, gym.spaces.Discrete(model.num_actions)
    env._reward = torch.as_tensor(model.r, dtype=torch.float32, device=env.device)
    env._cost = torch.as_tensor(model.c, dtype=torch.float32, device=env.device).permute(1, 2, 0)
    env.generator = torch.Generator(device=env.device)
    env.state = torch.zeros(num_envs, dtype=torch.int64, device=env.device)


def table_actions(env: VecEnv, action: torch.Tensor, name: str) -> torch.Tensor:
    """A :func:`tabular` env's actions ``[N, 1]`` as indices ``[N]``, each checked to be an action."""
    env.check_action(action)
    a = action[:, 0].to(device=env.device, dtype=torch.int64)
    if bool(((a < 0) | (a >= env.action_space.n)).any()):
        raise ValueError(f"{name} action must be in 0..{env.action_space.n - 1}, got {action.flatten().tolist()}")
    return a


def _probe_num_costs(make_one: Callable[[], gym.Env]) -> int:
    """K of an env that does not declare ``cost_names``: the length of ``info["cost"]`` on one seeded
    step of a throwaway instance. A missing cost, or a probe step that fails, counts as one
    constraint: the training env's own steps then report the problem (the contract check names it)."""
    env = make_one()
    try:
        env.reset(seed=0)
        env.action_space.seed(0)
        info = env.step(env.action_space.sample())[4]
        return int(np.size(info.get("cost", 0.0))) or 1
    except Exception:  # noqa: BLE001 - only K is wanted here; the real steps raise the real error
        return 1
    finally:
        env.close()


def declared_cost_names(env: gym.Env) -> Any:
    """The ``cost_names`` a gymnasium env (or one of its wrappers) declares, as it declares them; else None."""
    try:
        return env.get_wrapper_attr("cost_names")
    except AttributeError:
        return None


class GymVecEnv(VecEnv):
    """Gymnasium envs that report cost in ``info["cost"]`` (a number, or a 1-D array of K numbers),
    in gymnasium's synchronous vector env; K from the env's ``cost_names`` if it declares them, else
    from one probe step. SAME_STEP autoreset (the done step's final observation and cost come in
    ``final_obs``/``final_info``), never NEXT_STEP, the default, which gives a phantom step at every
    episode end. ``asynchronous=True`` steps the envs in worker processes (``AsyncVectorEnv``): worth
    it only where a step costs far more than the round trip (docs/benchmarks.md); its envs' state is
    then left to subclasses that know how to fetch it.
    """

    def __init__(
        self,
        make_one: Callable[[], gym.Env],
        num_envs: int,
        device: str | torch.device = "cpu",
        asynchronous: bool = False,
        env_id: str = "env",
        cost_names: Sequence[str] | None = None,
    ) -> None:
        vector = AsyncVectorEnv if asynchronous else SyncVectorEnv
        self.envs = vector([make_one for _ in range(num_envs)], autoreset_mode=AutoresetMode.SAME_STEP)
        self.num_envs = num_envs
        obs_space = self.envs.single_observation_space
        act_space = self.envs.single_action_space
        try:
            check_action_space(act_space, env_id)
        except ValueError:
            self.envs.close()
            raise
        self._action_space = act_space
        self.obs_dim = int(np.prod(obs_space.shape))
        # Actions are stored flat (cmdp_rl/rollout/actions.py): a box's numbers, or one index per component.
        self.action_dim = action_dim(act_space)
        self.device = torch.device(device)
        # the range of each stored entry: a box's bounds, a discrete index's [0, n - 1]
        low, high = action_bounds(act_space)
        self.action_low, self.action_high = low.to(self.device), high.to(self.device)
        # an async vector env keeps its envs in worker processes: ask a local probe copy instead
        local = getattr(self.envs, "envs", None)
        names = declared_cost_names(local[0]) if local else None
        self.num_costs = len(names) if names is not None else _probe_num_costs(make_one)
        self._cost_names = tuple(names) if names is not None else ()  # () reads as the default names
        if cost_names is not None:  # the user's names (env.cost_names), one per cost the env reports
            if len(cost_names) != self.num_costs:
                self.envs.close()
                raise ConfigError(
                    f"env.cost_names must name the {self.num_costs} cost(s) {env_id} reports, "
                    f"got {len(cost_names)}: {list(cost_names)}"
                )
            self._cost_names = tuple(cost_names)
        self._zeros = np.zeros((num_envs, self.num_costs), dtype=np.float32)

    def _cost(self, info: dict) -> np.ndarray:
        """``info["cost"]`` of the N envs as ``[N, K]`` float32 (a fresh array)."""
        return np.array(info.get("cost", self._zeros), dtype=np.float32).reshape(self.num_envs, self.num_costs)

    def _obs(self, obs: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.asarray(obs, dtype=np.float32).reshape(self.num_envs, self.obs_dim)).to(self.device)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        obs, _ = self.envs.reset(seed=seed)
        return self._obs(obs)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        # gymnasium's partial reset (sync and async alike); the other envs' observations are unchanged.
        mask = rows.detach().cpu().numpy().astype(bool).reshape(self.num_envs)
        obs, _ = self.envs.reset(options={"reset_mask": mask})
        return self._obs(obs)[rows.to(self.device)]

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        obs, reward, terminated, truncated, info = self.envs.step(to_env(action, self._action_space))
        cost = self._cost(info)
        next_obs = obs
        if "final_obs" in info:
            done_mask = info["_final_obs"]
            next_obs = np.array(obs, dtype=np.float32, copy=True)
            next_obs[done_mask] = np.stack(info["final_obs"][done_mask])
            cost[done_mask] = self._cost(info["final_info"])[done_mask]
        n = self.num_envs
        return Step(
            next_obs=self._obs(next_obs),
            reward=torch.from_numpy(np.asarray(reward, dtype=np.float32)).view(n, 1).to(self.device),
            cost=torch.from_numpy(cost).to(self.device),
            terminated=torch.from_numpy(np.asarray(terminated, dtype=bool)).view(n, 1).to(self.device),
            truncated=torch.from_numpy(np.asarray(truncated, dtype=bool)).view(n, 1).to(self.device),
            obs=self._obs(obs),
        )

    def state_dict(self) -> dict[str, Any]:
        """Each env's state, wrappers included (see ``envs/env_state.py``). In SAME_STEP mode the
        vector env itself holds nothing between steps."""
        return {"num_envs": self.num_envs, "envs": [env_state(env) for env in self.envs.envs]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["num_envs"] != self.num_envs:
            raise ValueError(f"env: saved state is for {state['num_envs']} envs, this one has {self.num_envs}")
        if not isinstance(self.envs, SyncVectorEnv):
            raise NotImplementedError("env: envs in worker processes (asynchronous) cannot restore a saved state")
        for env, saved in zip(self.envs.envs, state["envs"]):
            load_env_state(env, saved)

    def close(self) -> None:
        self.envs.close()
