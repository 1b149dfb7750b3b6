"""Small gymnasium envs that report a cost, for the discrete-action, env-contract and several-constraint tests.
Importing this module registers them; from a subprocess, ``env.id=helpers.cost_envs:<id>`` imports it
(with ``tests/`` on ``PYTHONPATH``).

- ``cost_test/Match-v0``: a contextual bandit with ``Discrete(4)`` actions. Each step shows a
  context c in {0..3} (one-hot, drawn uniformly); reward 1 if the action equals c; the action 3
  costs 1 whatever the context. Episodes are 8 steps (truncated). A uniform policy earns 2 per
  episode at cost 2; the best one 8 at cost 2; the best one with no cost 6.
- ``cost_test/MultiMatch-v0``: the same with ``MultiDiscrete([3, 2])`` actions and two contexts
  (c0 in {0, 1, 2}, c1 in {0, 1}): reward 0.5 per matched component; the first component's action 2
  costs 1.
- ``cost_test/Broken-v0``: a 1-D Box env that breaks the contract from step ``at`` on (counted over
  the env's life, resets included): ``fault`` is ``nan_reward``, ``inf_obs``, ``nan_cost`` or
  ``negative_cost``.
- ``cost_test/Tuple-v0``: an env with a ``Tuple`` action space, which no head supports.
- ``cmdp_rl_test/TwoCost-v0`` (:class:`TwoCost`): K = 2 costs whose episode sums are worked out by hand;
  :func:`two_cost_cfg` is a short ppo_lag run on it with a budget per cost.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from cmdp_rl.envs import GymVecEnv

MATCH_ID = "cost_test/Match-v0"
MULTI_MATCH_ID = "cost_test/MultiMatch-v0"
BROKEN_ID = "cost_test/Broken-v0"
TUPLE_ID = "cost_test/Tuple-v0"
TWO_COST_ID = "cmdp_rl_test/TwoCost-v0"
TWO_COST_NAMES = ("hazard_a", "hazard_b")


class Match(gym.Env):
    def __init__(self, sizes: tuple[int, ...] = (4,)) -> None:
        self.sizes = tuple(sizes)
        self.observation_space = spaces.Box(0.0, 1.0, (sum(self.sizes),), np.float32)
        self.action_space = spaces.Discrete(self.sizes[0]) if len(self.sizes) == 1 else spaces.MultiDiscrete(self.sizes)
        self.context = np.zeros(len(self.sizes), dtype=np.int64)

    def _obs(self) -> np.ndarray:
        self.context = np.array([self.np_random.integers(n) for n in self.sizes])
        obs = np.zeros(sum(self.sizes), dtype=np.float32)
        offsets = np.cumsum((0, *self.sizes[:-1]))
        obs[offsets + self.context] = 1.0
        return obs

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self._obs(), {}

    def step(self, action):
        a = np.atleast_1d(np.asarray(action))
        assert a.shape == (len(self.sizes),) and np.issubdtype(a.dtype, np.integer), a
        reward = float(np.mean(a == self.context))
        cost = float(a[0] == self.sizes[0] - 1)
        return self._obs(), reward, False, False, {"cost": cost}


class Broken(gym.Env):
    observation_space = spaces.Box(-np.inf, np.inf, (2,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, fault: str = "nan_reward", at: int = 1) -> None:
        self.fault, self.at, self.t = fault, at, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(2, np.float32), {}

    def step(self, action):
        self.t += 1
        bad = self.t >= self.at
        obs = np.full(2, np.inf if bad and self.fault == "inf_obs" else 0.5, np.float32)
        reward = float("nan") if bad and self.fault == "nan_reward" else 0.0
        cost = {"nan_cost": float("nan"), "negative_cost": -0.5}.get(self.fault, 0.0) if bad else 0.0
        return obs, reward, False, False, {"cost": cost}


class TupleActions(Broken):
    action_space = spaces.Tuple((spaces.Discrete(2), spaces.Discrete(2)))


class TwoCost(gym.Env):
    """A 1-D Box action in [-1, 1]; episodes of ``length`` steps; observation t / length.

    - ``mode="fixed"``: reward = a, ``info["cost"] = [1, t]`` at step t = 1..length (independent of
      the action: an episode's costs are (length, length (length + 1) / 2)).
    - ``mode="learn"``: reward = a, ``info["cost"] = [a > 0, 0]``: the first constraint is paid for
      the rewarding actions, the second never.
    ``named``: declare ``cost_names`` (else the toolkit calls them cost_0, cost_1).
    """

    def __init__(self, length: int = 3, mode: str = "fixed", named: bool = True) -> None:
        self.observation_space = gym.spaces.Box(0.0, 1.0, (1,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.length, self.mode = length, mode
        if named:
            self.cost_names = TWO_COST_NAMES
        self.t = 0

    def _obs(self) -> np.ndarray:
        return np.array([self.t / self.length], dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self._obs(), {}

    def step(self, action):
        a = float(np.clip(action[0], -1.0, 1.0))
        self.t += 1
        if self.mode == "fixed":
            cost = np.array([1.0, float(self.t)])
        else:
            cost = np.array([float(a > 0), 0.0])
        return self._obs(), a, self.t >= self.length, False, {"cost": cost}


def two_cost_env(num_envs: int = 2, **kwargs) -> GymVecEnv:
    """``num_envs`` TwoCost envs (``kwargs``: its options) in the gymnasium backend."""
    return GymVecEnv(lambda: TwoCost(**kwargs), num_envs)


def two_cost_cfg(**overrides) -> dict:
    """A short run on :class:`TwoCost` (``mode="learn"``) with a budget per cost; ``overrides`` merge in."""
    cfg = {
        "env": {"name": "gym", "id": TWO_COST_ID, "num_envs": 2, "kwargs": {"length": 4, "mode": "learn"}},
        "algo": {"name": "ppo_lag", "update_epochs": 2, "num_minibatches": 2, "cost_limit": [0.5, 1.0]},
        "rollout_steps": 16,
        "total_steps": 6 * 32,
        "checkpoint_every": 100,
        "eval_episodes": 4,
        "log_interval": 1,
    }
    for k, v in overrides.items():
        if isinstance(v, dict) and k in cfg:
            cfg[k] = {**cfg[k], **v}
        else:
            cfg[k] = v
    if cfg["algo"]["name"] in ("ppo_lag", "trpo_lag"):  # pinned, as helpers.runs' TINY: the dual ascent these checks
        cfg["algo"]["multiplier"] = {"kind": "dual", "lr": 0.5, **cfg["algo"].get("multiplier", {})}  # compute by hand
        cfg["algo"].setdefault("advantage_scale", "raw")
    return cfg


def register() -> None:
    for env_id, entry, kwargs in (
        (MATCH_ID, Match, {}),
        (MULTI_MATCH_ID, Match, {"sizes": (3, 2)}),
        (BROKEN_ID, Broken, {}),
        (TUPLE_ID, TupleActions, {}),
        (TWO_COST_ID, TwoCost, {}),
    ):
        if env_id not in gym.registry:
            steps = 8 if "Match" in env_id else None if env_id == TWO_COST_ID else 50  # TwoCost ends its episodes
            gym.register(env_id, entry_point=entry, kwargs=kwargs, max_episode_steps=steps)


register()
