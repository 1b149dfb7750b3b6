"""env=gym: any registered env reporting cost in info["cost"], or Safety-Gymnasium's six-value step."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers.policies import ForwardPolicy

from cmdp_rl import Collector, finished_episodes, keys, load_config, make_env
from cmdp_rl.envs.gym_cost import SixValueStep, make_cost_env

SIX_ID = "cmdp_rl_test/SixValueCounter-v0"
FIVE_ID = "cmdp_rl_test/FiveValueCounter-v0"


class SixValueCounter(gym.Env):
    """Safety-Gymnasium's protocol: step returns (obs, reward, cost, terminated, truncated, info).

    The observation counts the steps; reward is the action; every third step costs 1; the episode
    terminates after ``length`` steps. No time limit of its own."""

    def __init__(self, length: int = 10):
        self.length = length
        self.observation_space = gym.spaces.Box(0.0, np.inf, (2,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.array([0.0, self.np_random.uniform()], np.float32), {"t": 0}

    def step(self, action):
        self.t += 1
        cost = 1.0 if self.t % 3 == 0 else 0.0
        obs = np.array([self.t, 0.0], np.float32)
        return obs, float(action[0]), cost, self.t >= self.length, False, {"t": self.t}


class FiveValueCounter(SixValueCounter):
    def step(self, action):
        obs, reward, cost, terminated, truncated, info = super().step(action)
        return obs, reward, terminated, truncated, {**info, "cost": cost}


if SIX_ID not in gym.registry:
    gym.register(SIX_ID, entry_point=SixValueCounter, max_episode_steps=7)
    gym.register(FIVE_ID, entry_point=FiveValueCounter, max_episode_steps=7)


def constant(value):
    return ForwardPolicy(lambda obs: torch.full((obs.shape[0], 1), value))


def test_six_value_adapter_moves_cost_into_info():
    env = SixValueStep(SixValueCounter())
    env.reset(seed=0)
    costs = []
    for _ in range(6):
        obs, reward, terminated, truncated, info = env.step(np.array([0.5], np.float32))
        costs.append(info["cost"])
        assert reward == 0.5 and info["t"] == obs[0]
    assert costs == [0.0, 0.0, 1.0, 0.0, 0.0, 1.0]


def test_six_value_adapter_refuses_a_five_value_env():
    env = SixValueStep(FiveValueCounter())
    env.reset(seed=0)
    with pytest.raises(ValueError, match="returned 5 values"):
        env.step(np.zeros(1, np.float32))


@pytest.mark.parametrize("env_id,step_api", [(SIX_ID, "six"), (FIVE_ID, "five")])
def test_both_protocols_train_the_same_batch(env_id, step_api):
    # registered limit 7 (truncation) before the env's own end at 10: episodes of 7 steps, costs at 3, 6
    cfg = load_config({"env": {"name": "gym", "id": env_id, "step_api": step_api, "num_envs": 2}})
    env = make_env(cfg.env)
    batch = Collector(env, constant(0.25), rollout_steps=14, seed=0).collect()
    nxt = batch[keys.NEXT]
    assert nxt[keys.COST][1, :, 0].tolist() == [0, 0, 1, 0, 0, 1, 0] * 2
    assert nxt[keys.TRUNCATED][0, :, 0].nonzero().view(-1).tolist() == [6, 13]
    assert not nxt[keys.TERMINATED].any()
    assert nxt[keys.OBS][0, 6, 0].item() == 7.0  # the done step keeps its final observation
    eps = finished_episodes(batch)
    assert eps["cost"].tolist() == [[2.0]] * 4 and eps["return"].tolist() == [1.75] * 4


def test_max_steps_overrides_the_registered_limit_and_kwargs_reach_the_constructor():
    for step_api, env_id in (("six", SIX_ID), ("five", FIVE_ID)):
        env = make_cost_env(env_id, step_api, max_steps=20, length=4)
        env.reset(seed=0)
        ends = [env.step(np.zeros(1, np.float32))[2] for _ in range(4)]
        assert ends == [False, False, False, True], step_api  # terminated by the env at length=4


def test_module_prefix_imports_the_module_first():
    # "cmdp_rl:..." imports cmdp_rl (which registers Reach1D) before the lookup, as gymnasium.make does
    env = make_cost_env("cmdp_rl:cmdp_rl/Reach1D-v0")
    env.reset(seed=0)
    assert env.step(np.array([0.1], np.float32))[-1]["cost"] == 0.0


def test_gym_reach1d_matches_the_native_env():
    native = make_env(load_config({"env": {"name": "reach1d", "num_envs": 2}}).env)
    wrapped = make_env(load_config({"env": {"name": "gym", "id": "cmdp_rl/Reach1D-v0", "num_envs": 2}}).env)
    a, b = native.reset(seed=3), wrapped.reset(seed=3)
    assert torch.equal(a, b)
    for t in range(120):
        act = torch.full((2, 1), 0.1 if t % 5 else -0.05)
        sa, sb = native.step(act), wrapped.step(act)
        for x, y in zip(sa, sb):
            assert torch.equal(x, y)


def test_an_env_without_cost_is_refused_with_its_id_named():
    env = make_env(load_config({"env": {"name": "gym", "id": "Pendulum-v1", "num_envs": 1}}).env)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"env.id=Pendulum-v1: the env's step reports no info\['cost'\]"):
        env.step(torch.zeros(1, 1))


@pytest.mark.parametrize(
    "env,field",
    [
        ({}, "env.id"),
        ({"id": "X-v0", "step_api": "seven"}, "env.step_api"),
        ({"id": "X-v0", "max_steps": -1}, "env.max_steps"),
        ({"id": "X-v0", "backend": "torch"}, "env.backend"),
    ],
)
def test_gym_env_config_errors_name_the_field(env, field):
    with pytest.raises(Exception) as err:
        load_config({"env": {"name": "gym", **env}})
    assert str(err.value).startswith(field), str(err.value)
