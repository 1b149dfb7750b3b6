"""The batched env interface the collector drives, and its gymnasium implementation.

Why not torchrl's ``EnvBase``/``GymWrapper``: on this machine torchrl's env + collector machinery
costs about 1.3 ms per step (specs, step_mdp, info readers), several times the cost of stepping
8 Reach1D envs. The collector only needs tensors in and tensors out, so envs expose exactly that.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Callable, NamedTuple

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from cmdp_rl.actions import action_dim, categories, check_action_space, is_discrete, to_env
from cmdp_rl.envs.env_state import env_state, load_env_state


class Step(NamedTuple):
    """One step of N envs. ``next_obs`` is what the step led to (the final observation where an
    episode ended, needed to bootstrap a truncated one); ``obs`` is what the agent acts on next
    (the reset observation where an episode ended). Reward, cost and flags are ``[N, 1]``."""

    next_obs: torch.Tensor
    reward: torch.Tensor
    cost: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor
    obs: torch.Tensor


class VecEnv(ABC):
    """N environments stepped together, with per-env auto-reset."""

    num_envs: int
    obs_dim: int
    action_dim: int
    action_low: torch.Tensor
    action_high: torch.Tensor
    device: torch.device

    @abstractmethod
    def reset(self, seed: int | None = None) -> torch.Tensor:
        """Reset every env; returns observations ``[N, obs_dim]``."""

    @abstractmethod
    def step(self, action: torch.Tensor) -> Step:
        """Apply ``action`` ``[N, action_dim]``; envs whose episode ended are reset."""

    def close(self) -> None:  # noqa: B027 - optional hook
        pass

    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs to continue exactly where this env stands: the episodes
        in progress and the envs' random generators. ``load_state_dict`` on a fresh env built from
        the same config restores it."""
        raise NotImplementedError(f"{type(self).__name__} cannot save its state, so a run on it cannot resume")

    def load_state_dict(self, state: dict[str, Any]) -> None:
        raise NotImplementedError(f"{type(self).__name__} cannot restore a saved state")

    @property
    def action_space(self) -> gym.Space:
        """One env's action space, which the agent's action distribution is chosen from
        (``policies/distributions.py``): the box ``[action_low, action_high]`` unless the env says
        otherwise."""
        return gym.spaces.Box(self.action_low.cpu().numpy(), self.action_high.cpu().numpy(), dtype=np.float32)

    def check_action(self, action: torch.Tensor) -> None:
        expected = (self.num_envs, self.action_dim)
        if tuple(action.shape) != expected:
            raise ValueError(f"action: expected shape {expected} (num_envs, action_dim), got {tuple(action.shape)}")


class GymVecEnv(VecEnv):
    """Gymnasium envs that report cost in ``info["cost"]``, in gymnasium's synchronous vector env.

    SAME_STEP autoreset: the done step's final observation and info (its cost) come in
    ``final_obs``/``final_info``. Never NEXT_STEP, the default, which would give a phantom step at
    every episode end.
    """

    def __init__(self, make_one: Callable[[], gym.Env], num_envs: int, device: str | torch.device = "cpu",
                 env_id: str = "env") -> None:
        self.envs = SyncVectorEnv([make_one for _ in range(num_envs)], autoreset_mode=AutoresetMode.SAME_STEP)
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
        # Actions are stored flat (cmdp_rl/actions.py): a box's numbers, or one index per component.
        self.action_dim = action_dim(act_space)
        # Gymnasium steps on the CPU; tensors handed out live on ``device``.
        self.device = torch.device(device)
        if is_discrete(act_space):  # the range of each stored index
            self.action_low = torch.zeros(self.action_dim, device=self.device)
            self.action_high = torch.tensor(categories(act_space), dtype=torch.float32, device=self.device) - 1
        else:
            self.action_low = torch.as_tensor(act_space.low, dtype=torch.float32, device=self.device).reshape(-1)
            self.action_high = torch.as_tensor(act_space.high, dtype=torch.float32, device=self.device).reshape(-1)
        self._zeros = np.zeros(num_envs, dtype=np.float32)

    @property
    def action_space(self) -> gym.Space:
        """The env's own action space (a box, or discrete actions)."""
        return self._action_space

    def _obs(self, obs: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.asarray(obs, dtype=np.float32).reshape(self.num_envs, self.obs_dim)).to(self.device)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        obs, _ = self.envs.reset(seed=seed)
        return self._obs(obs)

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        obs, reward, terminated, truncated, info = self.envs.step(to_env(action, self._action_space))
        cost = np.asarray(info.get("cost", self._zeros), dtype=np.float32)
        next_obs = obs
        if "final_obs" in info:
            done_mask = info["_final_obs"]
            next_obs = np.array(obs, dtype=np.float32, copy=True)
            next_obs[done_mask] = np.stack(info["final_obs"][done_mask])
            cost = cost.copy()
            cost[done_mask] = np.asarray(info["final_info"].get("cost", self._zeros), dtype=np.float32)[done_mask]
        n = self.num_envs
        return Step(
            next_obs=self._obs(next_obs),
            reward=torch.from_numpy(np.asarray(reward, dtype=np.float32)).view(n, 1).to(self.device),
            cost=torch.from_numpy(cost).view(n, 1).to(self.device),
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
        for env, saved in zip(self.envs.envs, state["envs"]):
            load_env_state(env, saved)

    def close(self) -> None:
        self.envs.close()
