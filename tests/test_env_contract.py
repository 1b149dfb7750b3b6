"""The env contract: deliberately broken toy envs, one per rule, each stopped with one line naming
the env, the env index, the step and the field; well-behaved envs pass."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from cmdp_rl.config.validation import ConfigError
from cmdp_rl.envs import GymVecEnv, Reach1D, TorchReach1D
from cmdp_rl.envs.contract import EnvContract, EnvContractError, check_env
from cmdp_rl.envs.grid.env import GRID_ID

BREAK_AT = 3  # the toy envs break on their third step


class Toy(gym.Env):
    """A well-behaved CMDP env (2-D float32 observation in [-1, 1], one cost) whose step values are
    replaced, from step BREAK_AT on, by whatever ``broken`` (step values -> step values) returns."""

    def __init__(
        self, broken=None, action_space=None, observation_space=None, cost_names=None, episode=50, break_at=BREAK_AT
    ):
        self.observation_space = observation_space or spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = action_space or spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        if cost_names is not None:
            self.cost_names = cost_names
        self.broken, self.episode, self.break_at = broken, episode, break_at

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self.observation_space.sample(), {}

    def step(self, action):
        self.t += 1
        out = (self.observation_space.sample(), 0.5, False, self.t >= self.episode, {"cost": 1.0})
        if self.broken is not None and self.t >= self.break_at:
            out = self.broken(*out)
        return out


def with_info(**info):
    return lambda o, r, te, tr, i: (o, r, te, tr, info)


def with_cost(cost):
    return lambda o, r, te, tr, i: (o, r, te, tr, {"cost": cost})


def at(field, value):
    pos = ("obs", "reward", "terminated", "truncated").index(field)
    return lambda *out: tuple(value if n == pos else v for n, v in enumerate(out))


def growing_cost(o, r, te, tr, i):  # one cost, then two
    return o, r, te, tr, {"cost": np.zeros(2)}


def message(env, **kw):
    with pytest.raises(EnvContractError) as exc:
        check_env(env, steps=10, **kw)
    text = str(exc.value)
    assert "\n" not in text
    return text


STEP = f"(env 0, step {BREAK_AT})"


@pytest.mark.parametrize(
    "broken, expected",
    [
        (with_info(other=1), "info[\"cost\"] is missing (info keys: ['other']); a CMDP env reports its cost there"),
        (with_cost(float("nan")), 'info["cost"] is nan; costs must be finite'),
        (with_cost(np.array([-np.inf], dtype=np.float32)), 'info["cost"] is -inf; costs must be finite'),
        (with_cost("1.0"), "info[\"cost\"] must be a number or a 1-D array of numbers, got '1.0' (str)"),
        (with_cost(True), 'info["cost"] must be a number or a 1-D array of numbers, got True'),
        (with_cost(np.zeros((1, 1))), 'info["cost"] must be a number or a 1-D array of numbers, got shape (1, 1)'),
        (
            with_cost(np.array([], dtype=np.float32)),
            'info["cost"] must be a number or a 1-D array of numbers, got shape (0,)',
        ),
        (growing_cost, 'info["cost"] has 2 entries, earlier steps had 1'),
        (
            with_cost(-0.5),
            'info["cost"] is -0.5; costs must be >= 0 in a CMDP (env.allow_negative_cost=true accepts signed costs)',
        ),
        (
            at("obs", np.array([0.0, 2.0], dtype=np.float32)),
            "observation [0. 2.] is outside observation_space Box(-1.0, 1.0, (2,), float32)",
        ),
        (at("obs", np.zeros(2, dtype=np.float64)), "observation has dtype float64, observation_space has float32"),
        (at("obs", np.zeros(3, dtype=np.float32)), "observation has shape (3,), observation_space has (2,)"),
        (at("obs", np.array([np.nan, 0.0], dtype=np.float32)), "observation is not finite: [nan 0.]"),
        (
            at("obs", [0.0, 0.0]),
            "observation must be a numpy array (observation_space is Box(-1.0, 1.0, (2,), float32)), got list",
        ),
        (at("reward", math.inf), "reward is inf; rewards must be finite"),
        (at("reward", np.float32("nan")), "reward is nan; rewards must be finite"),
        (at("reward", None), "reward must be a number, got None"),
        (at("terminated", 0), "terminated must be a bool, got 0 (int)"),
        (at("truncated", np.float64(1.0)), "truncated must be a bool, got np.float64(1.0) (float64)"),
        (
            lambda *out: out + (1.0,),
            "step() must return (observation, reward, terminated, truncated, info), got 6 values",
        ),
    ],
)
def test_each_breach_is_one_line_naming_env_index_step_and_field(broken, expected):
    assert message(Toy(broken)) == f"env Toy {STEP}: {expected}"


def test_the_message_names_the_registered_id_and_is_a_config_error():
    gym.register(id="ContractToy-v0", entry_point=Toy, kwargs={"broken": with_cost(float("nan"))})
    try:
        with pytest.raises(ConfigError, match=rf"^env ContractToy-v0 \(env 0, step {BREAK_AT}\): info\["):
            check_env(gym.make("ContractToy-v0"), steps=10)
    finally:
        del gym.registry["ContractToy-v0"]


def test_negative_costs_pass_when_allowed():
    assert check_env(Toy(with_cost(-0.5)), steps=10, allow_negative_cost=True) == EnvContract(1, ("cost_0",))
    assert "must be finite" in message(Toy(with_cost(-math.inf)), allow_negative_cost=True)


@pytest.mark.parametrize(
    "names, expected",
    [
        (("speed",), "cost_names has 1 names ('speed',), but info[\"cost\"] has 2 entries"),
        ("ab", "cost_names must be a sequence of strings, got 'ab'"),
        (("a", "a"), "cost_names must be distinct, got ('a', 'a')"),
        (("a", 2), "cost_names must be a sequence of strings, got ('a', 2)"),
    ],
)
def test_cost_names_must_name_each_cost_once(names, expected):
    text = message(Toy(with_cost(np.zeros(2)), cost_names=names, break_at=1))
    assert text.endswith(expected)


@pytest.mark.parametrize(
    "space, field",
    [
        (spaces.Dict({"x": spaces.Box(-1, 1, (1,))}), "action_space"),
        (spaces.Tuple((spaces.Discrete(2), spaces.Discrete(3))), "action_space"),
        (spaces.MultiBinary(3), "action_space"),
    ],
)
def test_unsupported_action_spaces_are_refused_before_stepping(space, field):
    text = message(Toy(action_space=space))
    assert text.startswith(f"env Toy: {field} ") and "supported: Box, Discrete, MultiDiscrete" in text


def test_unsupported_observation_space_is_refused():
    text = message(Toy(observation_space=spaces.Dict({"x": spaces.Box(-1, 1, (1,))})))
    assert (
        text.startswith("env Toy: observation_space ")
        and "supported: Box, Discrete, MultiDiscrete, MultiBinary" in text
    )


def test_well_behaved_envs_pass_and_report_their_costs():
    assert check_env(gym.make(GRID_ID), steps=200) == EnvContract(2, ("hazard_a", "hazard_b"))
    assert check_env(gym.make("cmdp_rl/Reach1D-v0"), steps=200) == EnvContract(1, ("cost_0",))
    # episodes end inside the check (every 5 steps) and the reset observation is checked too
    multi = Toy(
        lambda o, r, te, tr, i: (o, r, te, tr, {"cost": np.float32(0.0)}),
        action_space=spaces.MultiDiscrete([3, 2]),
        observation_space=spaces.Discrete(5),
        episode=5,
    )
    assert check_env(multi, steps=30) == EnvContract(1, ("cost_0",))
    assert check_env(GymVecEnv(Reach1D, 2), steps=50).num_costs == 1
    assert check_env(TorchReach1D(16), steps=50).num_costs == 1


def test_a_vector_env_names_the_env_that_broke():
    good = Toy
    vec = gym.vector.SyncVectorEnv([good, good, lambda: Toy(with_cost(float("nan")))])
    assert message(vec) == f"env Toy (env 2, step {BREAK_AT}): " + 'info["cost"] is nan; costs must be finite'


class BrokenTorchReach1D(TorchReach1D):
    """The batched torch Reach1D, with a NaN cost in env 3 from step 5 on, or a negative one."""

    def __init__(self, *args, value=float("nan"), **kw):
        super().__init__(*args, **kw)
        self.t, self.value = 0, value

    def step(self, action):
        out = super().step(action)
        self.t += 1
        if self.t >= 5:
            cost = out.cost.clone()
            cost[3] = self.value
            out = out._replace(cost=cost)
        return out


def test_a_batched_torch_env_is_checked_on_its_tensors():
    assert (
        message(BrokenTorchReach1D(8))
        == 'env BrokenTorchReach1D (env 3, step 5): info["cost"] is nan; costs must be finite'
    )
    assert "costs must be >= 0" in message(BrokenTorchReach1D(8, value=-1.0))
    assert check_env(BrokenTorchReach1D(8, value=-1.0), steps=10, allow_negative_cost=True).num_costs == 1


def test_a_batched_torch_env_with_a_non_finite_observation():
    class NaNObs(TorchReach1D):
        def step(self, action):
            out = super().step(action)
            obs = out.next_obs.clone()
            obs[1, 0] = float("inf")
            return out._replace(next_obs=obs)

    assert message(NaNObs(4)).startswith("env NaNObs (env 1, step 1): observation is not finite: [inf")


def test_every_env_of_a_vector_env_must_report_the_same_number_of_costs():
    two = lambda: Toy(with_cost(np.array([0.0, 1.0])), break_at=1)  # noqa: E731
    vec = gym.vector.SyncVectorEnv([Toy, two])
    assert message(vec) == 'env Toy (env 1, step 1): info["cost"] has 2 entries, earlier steps had 1'
    both = gym.vector.SyncVectorEnv([two, two])
    assert check_env(both, steps=5) == EnvContract(2, ("cost_0", "cost_1"))
    bad = gym.vector.SyncVectorEnv([lambda: Toy(with_cost(np.array([0.0, np.nan])), break_at=1)])
    assert message(bad).endswith('info["cost"] is [ 0. nan]; costs must be finite')
