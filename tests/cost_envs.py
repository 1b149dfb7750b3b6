"""Small gymnasium envs that report a cost, for the discrete-action and env-contract tests.
Importing this module registers them; from a subprocess, ``env.id=cost_envs:<id>`` imports it
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
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

MATCH_ID = "cost_test/Match-v0"
MULTI_MATCH_ID = "cost_test/MultiMatch-v0"
BROKEN_ID = "cost_test/Broken-v0"
TUPLE_ID = "cost_test/Tuple-v0"


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


def register() -> None:
    for env_id, entry, kwargs in (
        (MATCH_ID, Match, {}),
        (MULTI_MATCH_ID, Match, {"sizes": (3, 2)}),
        (BROKEN_ID, Broken, {}),
        (TUPLE_ID, TupleActions, {}),
    ):
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=entry, kwargs=kwargs, max_episode_steps=8 if "Match" in env_id else 50)


register()
