"""The CMDP contract an env must keep, checked by stepping it briefly before training
(:func:`check_env`) and on every rollout (:func:`check_rollout`): the first breach stops the run with
one line naming the env, the env index, the step and the field. What is checked, and why a negative
cost is a breach: docs/guide/env_contract.md. The check steps and resets the env it is given: pass
one built for it, not the training env (whose random generators it would move on).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from cmdp_rl.config.validation import ConfigError
from cmdp_rl.envs.vector import declared_cost_names, default_cost_names
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.actions import SUPPORTED, hybrid

ACTION_SPACES = (spaces.Box, spaces.Discrete, spaces.MultiDiscrete)
OBSERVATION_SPACES = (spaces.Box, spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary)
COST = 'info["cost"]'


class EnvContractError(ConfigError):
    """An env breaks the CMDP contract (a :class:`ConfigError`: ``train.py`` says so in one line)."""


@dataclass(frozen=True)
class EnvContract:
    """What the check found: the number of costs K and their names (the env's, else ``cost_k``)."""

    num_costs: int
    cost_names: tuple[str, ...]


def _short(value: Any) -> str:
    """A value's repr on one short line."""
    if isinstance(value, (np.ndarray, torch.Tensor)):
        text = np.array2string(np.asarray(value), threshold=6, edgeitems=2, max_line_width=10**6)
    else:
        text = repr(value)
    text = " ".join(text.split())
    return text if len(text) <= 80 else text[:77] + "..."


class Checker:
    """Checks one env's (or one batch's) steps; remembers K across steps and envs. An env that checks
    its own raw steps (``check_contract``: a multi-agent env names the agent) uses it too."""

    def __init__(self, env_id: str, cost_names: Any, allow_negative_cost: bool) -> None:
        self.env_id = env_id
        self.allow_negative_cost = allow_negative_cost
        self.num_costs: int | None = None
        self.cost_names = self._names(cost_names)

    def fail(self, where: tuple[int, int] | None, field: str, problem: str) -> None:
        at = "" if where is None else f" (env {where[0]}, {'reset' if where[1] == 0 else f'step {where[1]}'})"
        raise EnvContractError(f"env {self.env_id}{at}: {field} {problem}")

    def _names(self, names: Any) -> tuple[str, ...] | None:
        if names is None:
            return None
        if isinstance(names, str) or not isinstance(names, Sequence) or not all(isinstance(n, str) for n in names):
            self.fail(None, "cost_names", f"must be a sequence of strings, got {_short(names)}")
        if len(set(names)) != len(names):
            self.fail(None, "cost_names", f"must be distinct, got {_short(tuple(names))}")
        return tuple(names)

    def spaces(self, action_space: Any, observation_space: Any) -> None:
        if not isinstance(action_space, ACTION_SPACES) and hybrid(action_space) is None:
            self.fail(None, "action_space", f"{action_space} is not supported; supported: {SUPPORTED}")
        if not isinstance(observation_space, OBSERVATION_SPACES):
            self.fail(
                None,
                "observation_space",
                f"{observation_space} is not supported; supported: Box, Discrete, MultiDiscrete, MultiBinary",
            )

    def observation(self, where: tuple[int, int], obs: Any, space: gym.Space, field: str = "observation") -> None:
        if isinstance(space, spaces.Box):
            if not isinstance(obs, np.ndarray):
                self.fail(
                    where, field, f"must be a numpy array (observation_space is {space}), got {type(obs).__name__}"
                )
            if obs.shape != space.shape:
                self.fail(where, field, f"has shape {obs.shape}, observation_space has {space.shape}")
            if not np.can_cast(obs.dtype, space.dtype):
                self.fail(where, field, f"has dtype {obs.dtype}, observation_space has {space.dtype}")
            if obs.dtype.kind == "f" and not np.isfinite(obs).all():
                self.fail(where, field, f"is not finite: {_short(obs)}")
        if not space.contains(obs):
            self.fail(where, field, f"{_short(obs)} is outside observation_space {space}")

    def reward(self, where: tuple[int, int], reward: Any) -> None:
        if isinstance(reward, (bool, np.bool_)) or not isinstance(reward, numbers.Real):
            self.fail(where, "reward", f"must be a number, got {_short(reward)}")
        if not np.isfinite(float(reward)):
            self.fail(where, "reward", f"is {float(reward)}; rewards must be finite")

    def flag(self, where: tuple[int, int], name: str, value: Any) -> None:
        if not isinstance(value, (bool, np.bool_)):
            self.fail(where, name, f"must be a bool, got {_short(value)} ({type(value).__name__})")

    def cost(self, where: tuple[int, int], info: Any) -> None:
        if not isinstance(info, dict):
            self.fail(where, "info", f"must be a dict, got {type(info).__name__}")
        if "cost" not in info:
            self.fail(
                where, COST, f"is missing (info keys: {sorted(map(str, info))}); a CMDP env reports its cost there"
            )
        value, wanted = info["cost"], "must be a number or a 1-D array of numbers, got"
        if isinstance(value, (bool, np.bool_)):
            self.fail(where, COST, f"{wanted} {value!r}")
        if isinstance(value, numbers.Real):
            cost = np.array([float(value)])
        elif isinstance(value, (np.ndarray, list, tuple, torch.Tensor)):
            cost = np.asarray(value)
            if cost.dtype.kind not in "iuf":
                self.fail(where, COST, f"{wanted} {_short(value)}")
            cost = cost.reshape(1) if cost.ndim == 0 else cost
            if cost.ndim != 1 or cost.size == 0:
                self.fail(where, COST, f"{wanted} shape {cost.shape}")
        else:
            self.fail(where, COST, f"{wanted} {_short(value)} ({type(value).__name__})")
        self.cost_vector(where, cost)

    def cost_vector(self, where: tuple[int, int], cost: np.ndarray) -> None:
        k = cost.shape[-1]
        if self.num_costs is None:
            self.num_costs = k
            if self.cost_names is not None and len(self.cost_names) != k:
                self.fail(
                    where,
                    "cost_names",
                    f"has {len(self.cost_names)} names {_short(self.cost_names)}, but {COST} has {k} entries",
                )
        elif k != self.num_costs:
            self.fail(where, COST, f"has {k} entries, earlier steps had {self.num_costs}")
        shown = _short(cost) if k > 1 else repr(float(cost[0]))
        if not np.isfinite(cost).all():
            self.fail(where, COST, f"is {shown}; costs must be finite")
        if not self.allow_negative_cost and (cost < 0).any():
            self.fail(
                where,
                COST,
                f"is {shown}; costs must be >= 0 in a CMDP (env.allow_negative_cost=true accepts signed costs)",
            )

    def result(self) -> EnvContract:
        k = self.num_costs or 1
        return EnvContract(k, self.cost_names or default_cost_names(k))


def _check_gym_envs(
    envs: Sequence[gym.Env], steps: int, seed: int, allow_negative_cost: bool, env_id: str | None
) -> EnvContract:
    """Each gymnasium env in turn: reset, ``steps`` random actions, a reset after every episode end."""
    first = envs[0]
    env_id = env_id or (first.spec.id if first.spec is not None else type(first.unwrapped).__name__)
    check = Checker(env_id, declared_cost_names(first), allow_negative_cost)
    for index, env in enumerate(envs):
        check.spaces(env.action_space, env.observation_space)
        env.action_space.seed(seed + index)
        out = env.reset(seed=seed + index)
        if not (isinstance(out, tuple) and len(out) == 2):
            check.fail((index, 0), "reset()", f"must return (observation, info), got {_short(out)}")
        check.observation((index, 0), out[0], env.observation_space)
        for t in range(1, steps + 1):
            out = env.step(env.action_space.sample())
            if not (isinstance(out, tuple) and len(out) == 5):
                n = len(out) if isinstance(out, tuple) else type(out).__name__
                check.fail(
                    (index, t),
                    "step()",
                    f"must return (observation, reward, terminated, truncated, info), got {n} values",
                )
            obs, reward, terminated, truncated, info = out
            check.observation((index, t), obs, env.observation_space)
            check.reward((index, t), reward)
            check.flag((index, t), "terminated", terminated)
            check.flag((index, t), "truncated", truncated)
            check.cost((index, t), info)
            if terminated or truncated:
                obs, _ = env.reset()
                check.observation((index, t), obs, env.observation_space, "observation after reset")
    return check.result()


def _check_tensor_env(env: Any, steps: int, seed: int, allow_negative_cost: bool, env_id: str | None) -> EnvContract:
    """A batched torch env (``cmdp_rl.envs.VecEnv``): the same rules on its ``[N, ...]`` tensors,
    vectorised over the batch; the first failing env is named."""
    check = Checker(env_id or type(env).__name__, getattr(env, "cost_names", None), allow_negative_cost)
    n = env.num_envs
    gen = torch.Generator(device=env.device).manual_seed(seed)

    def first_bad(bad: torch.Tensor) -> int:
        return int(torch.nonzero(bad.reshape(n, -1).any(-1))[0, 0])

    def batch(t: int, field: str, value: torch.Tensor, shape: tuple[int, ...], kind: str = "") -> None:
        """``kind``: the dtype wanted, "float" (and finite), "bool", or any (and finite)."""
        if tuple(value.shape) != shape:
            check.fail((0, t), field, f"has shape {tuple(value.shape)} over the batch, expected {shape}")
        if (kind == "float" and not value.dtype.is_floating_point) or (kind == "bool" and value.dtype != torch.bool):
            check.fail((0, t), field, f"has dtype {value.dtype}")
        if kind != "bool" and not torch.isfinite(value).all():
            i = first_bad(~torch.isfinite(value))
            check.fail((i, t), field, f"is not finite: {_short(value[i].cpu())}")

    obs = env.reset(seed=seed)
    batch(0, "observation", obs, (n, env.obs_dim), "float")
    low, high = env.action_low, env.action_high
    for t in range(1, steps + 1):
        u = torch.rand((n, env.action_dim), generator=gen, device=env.device)
        step = env.step(low + (high - low) * u)
        for field, value in (("observation", step.next_obs), ("observation after reset", step.obs)):
            batch(t, field, value, (n, env.obs_dim), "float")
        batch(t, "reward", step.reward, (n, 1))
        for name in ("terminated", "truncated"):
            batch(t, name, getattr(step, name), (n, 1), "bool")
        cost = step.cost
        if cost.dim() != 2 or cost.shape[0] != n:
            check.fail((0, t), COST, f"has shape {tuple(cost.shape)} over the batch, expected ({n}, K)")
        bad = ~torch.isfinite(cost) | ((cost < 0) & (not allow_negative_cost))
        i = first_bad(bad) if bad.any() else 0
        check.cost_vector((i, t), cost[i].detach().cpu().numpy().astype(np.float64))
    return check.result()


def contract_options(env_cfg: Any) -> tuple[str, bool]:
    """How contract messages name the env, and whether it allows negative costs (``EnvOptions``)."""
    return env_cfg.env_id(), bool(env_cfg.allow_negative_cost)


def check_rollout(batch: Any, env_id: str, allow_negative_cost: bool = False, first_step: int = 1) -> None:
    """The per-rollout part of the contract on a collector batch ``[N, T]`` (before any scaling):
    observations, rewards and costs finite, costs not negative unless ``allow_negative_cost``.
    ``first_step``: each env's step number of the batch's first step (1-based), for the message.
    A batch that fails the cheap test is searched for its first breach (earliest step, then lowest
    env index); one whose finite values only overflowed a sum passes.
    """
    nxt = batch.get(keys.NEXT)
    obs, next_obs = batch.get(keys.OBS), nxt.get(keys.OBS)
    reward, cost = nxt.get(keys.REWARD), nxt.get(keys.COST)
    ok = torch.isfinite(obs.sum() + next_obs.sum() + reward.sum() + cost.sum())
    if not allow_negative_cost:
        ok = ok & (cost.min() >= 0)
    if bool(ok):
        return
    n, t_len = batch.shape[:2]
    check = Checker(env_id, None, allow_negative_cost)

    def first(bad: torch.Tensor) -> tuple[int, int] | None:
        """(t, i) of the earliest breach in ``bad`` ``[N, T, ...]``, or None."""
        hits = torch.nonzero(bad.reshape(n, t_len, -1).any(-1).T)  # rows (t, i), in order of t then i
        return None if hits.numel() == 0 else (int(hits[0, 0]), int(hits[0, 1]))

    bad_cost = ~torch.isfinite(cost) | ((cost < 0) & (not allow_negative_cost))
    # (t offset of the env step the entry came from, entry, breach mask); root observations at t
    # were returned by step t - 1 (by the reset at step 0).
    found = []
    for offset, name, value, bad in (
        (-1, "observation", obs, ~torch.isfinite(obs)),
        (0, "observation", next_obs, ~torch.isfinite(next_obs)),
        (0, "reward", reward, ~torch.isfinite(reward)),
        (0, COST, cost, bad_cost),
    ):
        hit = first(bad)
        if hit is not None:
            found.append((first_step + hit[0] + offset, hit[1], name, value[hit[1], hit[0]]))
    if not found:
        return
    step, i, name, value = min(found, key=lambda f: (f[0], f[1]))
    where = (i, step)
    if name == COST:
        check.cost_vector(where, value.detach().cpu().reshape(-1).numpy().astype(np.float64))
    if name == "reward":
        check.reward(where, float(value.reshape(-1)[0]))
    check.fail(where, name, f"is not finite: {_short(value.detach().cpu())}")


def check_env(
    env: Any, steps: int = 100, seed: int = 0, allow_negative_cost: bool = False, env_id: str | None = None
) -> EnvContract:
    """Step ``env`` (a gymnasium env, a gymnasium ``SyncVectorEnv``, or a ``cmdp_rl.envs.VecEnv``)
    ``steps`` times per env with random actions and raise :class:`EnvContractError` at the first
    breach of the CMDP contract; return K and the cost names found. ``env_id`` names the env in the
    message (default: its registered id, else its class).
    """
    if isinstance(env, gym.Env):
        return _check_gym_envs([env], steps, seed, allow_negative_cost, env_id)
    own = getattr(env, "check_contract", None)  # an env that checks its own raw steps (multi_agent.py)
    if own is not None:
        return own(steps, seed, allow_negative_cost, env_id)
    # cmdp_rl's GymVecEnv keeps its SyncVectorEnv as .envs
    vector = env if isinstance(env, gym.vector.VectorEnv) else getattr(env, "envs", env)
    if isinstance(vector, gym.vector.SyncVectorEnv):
        return _check_gym_envs(list(vector.envs), steps, seed, allow_negative_cost, env_id)
    if isinstance(vector, gym.vector.VectorEnv):
        raise TypeError(f"check_env: pass the single env or a SyncVectorEnv, got {type(vector).__name__}")
    return _check_tensor_env(env, steps, seed, allow_negative_cost, env_id)
