"""The collector keeps reward and cost apart and gets episode ends right."""

import pytest
import torch

from cmdp_rl import Collector, finished_episodes, keys
from cmdp_rl.envs import GymVecEnv, Reach1D


class ConstantPolicy:
    """The collector's side of an agent (``act``, ``in_keys``, ``initial_state``): a constant
    action, plus Gaussian noise of std ``noise`` from torch's global generator."""

    in_keys = [keys.OBS]

    def __init__(self, value, noise=0.0):
        self.value, self.noise = value, noise

    def initial_state(self, num_envs, device="cpu"):
        return {}

    def act(self, d, deterministic=False):
        action = torch.full((d[keys.OBS].shape[0], 1), self.value)
        if self.noise:
            action = action + self.noise * torch.randn_like(action)
        return {keys.ACTION: action}


def policy(value):
    return ConstantPolicy(value)


def test_batch_layout_costs_and_episode_ends():
    # max_steps=7 with 20 steps per call: episodes end inside and across collect() calls
    env = GymVecEnv(lambda: Reach1D(max_steps=7, obs_noise=0.0), 3)
    col = Collector(env, policy(0.1), rollout_steps=20, seed=0)
    b = col.collect()
    assert b.batch_size == torch.Size([3, 20])
    nxt = b[keys.NEXT]
    # pushing at the bound: moves at steps 1-3, bumps the wall at steps 4..7 of each episode
    per_episode_cost = torch.tensor([0, 0, 0, 1, 1, 1, 1], dtype=torch.float32)
    expected_cost = per_episode_cost.repeat(3)[:20]
    assert torch.equal(nxt[keys.COST][0, :, 0], expected_cost)
    assert torch.equal(
        nxt[keys.REWARD][0, :, 0] != 0, expected_cost.eq(0) & torch.tensor([1, 1, 1, 0, 0, 0, 0]).repeat(3)[:20].bool()
    )
    done = nxt[keys.DONE][0, :, 0]
    assert done.nonzero().view(-1).tolist() == [6, 13]
    assert torch.equal(nxt[keys.TRUNCATED][0, :, 0], done) and not nxt[keys.TERMINATED].any()
    # the done step keeps its final observation (x = 0.4); the next step starts from the reset one
    assert abs(nxt[keys.OBS][0, 6, 0].item() - 0.4) < 1e-6 and abs(b[keys.OBS][0, 7, 0].item() - 0.1) < 1e-6
    assert b[keys.IS_INIT][0, :, 0].nonzero().view(-1).tolist() == [0, 7, 14]
    eps = finished_episodes(b)
    assert eps["cost"].tolist() == [[4.0]] * 6 and eps["length"].tolist() == [7.0] * 6
    assert torch.allclose(eps["return"], torch.full((6,), 0.3), atol=1e-6)
    assert col.total_steps == 60
    # the episode in progress continues into the next call
    b2 = col.collect()
    assert b2[keys.NEXT][keys.DONE][0, :, 0].nonzero().view(-1).tolist() == [0, 7, 14]
    assert b2[keys.NEXT][keys.EPISODE_COST][0, 0, 0].item() == 4.0


def test_cost_on_the_done_step_is_kept():
    # wall=pass, start right below the wall, 1-step episodes: every step is a done step with cost 1
    env = GymVecEnv(lambda: Reach1D(wall="pass", start=0.45, max_steps=1), 2)
    b = Collector(env, policy(0.1), rollout_steps=4, seed=0).collect()
    assert b[keys.NEXT][keys.COST].sum().item() == 8.0
    assert finished_episodes(b)["cost"].tolist() == [[1.0]] * 8  # [E, K]: one cost


def _mlp_agent_and_env(backend="gym", n=4):
    from cmdp_rl import load_config, make_agent, make_env

    cfg = load_config({"env": {"backend": backend, "num_envs": n, "max_steps": 9}})
    env = make_env(cfg.env)
    torch.manual_seed(0)
    return make_agent(cfg.policy, env), cfg


@pytest.mark.parametrize("deterministic", [False, True])
def test_agent_batch_equals_the_training_pass(deterministic):
    """What the agent stores while acting one step at a time (distribution parameters, action,
    log-prob) is what the training pass (``Agent.dist`` on the batch's training units) gives for
    the same steps; the deterministic action is the mean, a sampled one is not; a seeded collector
    repeats its batches."""
    from cmdp_rl import make_env

    agent, cfg = _mlp_agent_and_env()
    batches = []
    for _ in range(2):
        torch.manual_seed(1)
        col = Collector(make_env(cfg.env), agent, 20, seed=3, deterministic=deterministic)
        batches.append([col.collect(), col.collect()])
    for b, again in zip(*batches):
        assert {keys.ACTION, keys.LOG_PROB, keys.LOC, keys.SCALE} <= set(b.keys())
        assert b[keys.ACTION].shape == b[keys.LOC].shape == (4, 20, 1) and b[keys.LOG_PROB].shape == (4, 20)
        assert b[keys.ACTION].dtype == b[keys.LOG_PROB].dtype == torch.float32
        assert (b == again).all()
        units = agent.training_units({k: b.get(k) for k in [*agent.in_keys, keys.ACTION]})
        with torch.no_grad():
            dist = agent.dist(units)
            log_prob = dist.log_prob(units[keys.ACTION])
        assert torch.allclose(dist.mean, b[keys.LOC].flatten(0, 1), atol=1e-6)
        assert torch.allclose(dist.stddev, b[keys.SCALE].flatten(0, 1))
        assert torch.allclose(log_prob, b[keys.LOG_PROB].flatten(0, 1), atol=1e-5)
        if deterministic:
            assert torch.equal(b[keys.ACTION], b[keys.LOC])
        else:
            assert (b[keys.ACTION] != b[keys.LOC]).all()
            z = (b[keys.ACTION] - b[keys.LOC]) / b[keys.SCALE]  # standardized samples: about N(0, 1)
            assert abs(z.mean().item()) < 0.5 and 0.6 < z.std().item() < 1.4


class CountingPolicy:
    """A stateful policy: it reads its state from the root and returns the next one under "next",
    as the agent's recurrent bodies do; its initial state is given by ``initial_state``."""

    in_keys = [keys.OBS, keys.IS_INIT, "count"]

    def initial_state(self, num_envs, device="cpu"):
        return {"count": torch.zeros(num_envs, 1)}

    def act(self, d, deterministic=False):
        count = d["count"]
        return {keys.ACTION: torch.full((count.shape[0], 1), 0.1), (keys.NEXT, "count"): count + 1}


def test_state_written_under_next_is_carried_to_the_next_step():
    policy = CountingPolicy()
    env = GymVecEnv(lambda: Reach1D(max_steps=5, obs_noise=0.0), 2)
    col = Collector(env, policy, rollout_steps=7, seed=0)
    b = col.collect()
    expected = torch.tensor([0, 1, 2, 3, 4, 0, 1], dtype=torch.float32)
    assert torch.equal(b["count"][0, :, 0], expected)
    assert torch.equal(b[keys.NEXT]["count"][1, :, 0], expected + 1)
    b2 = col.collect()  # the state carries across calls
    assert b2["count"][0, 0, 0].item() == 2.0


def test_state_dict_continues_the_same_trajectories():
    """A collector restored from state_dict() on fresh envs collects what the original would
    have: next observations, running episode sums and each env's generator all come back. Both
    ways an env saves itself are checked: Reach1D's own state_dict, and pickling (a wrapped env)."""
    import gymnasium as gym

    from cmdp_rl.envs import GymVecEnv

    def noisy(value):
        return ConstantPolicy(value, noise=0.05)

    for make_one in (
        lambda: Reach1D(max_steps=9, start=[0.2, 0.45], wall="pass"),
        lambda: gym.wrappers.RecordEpisodeStatistics(Reach1D(max_steps=9, start=[0.2, 0.45])),
    ):
        torch.manual_seed(0)
        col = Collector(GymVecEnv(make_one, 3), noisy(0.04), rollout_steps=13, seed=5)
        col.collect()
        saved, rng = col.state_dict(), torch.get_rng_state()
        expected = col.collect()
        fresh = Collector(GymVecEnv(make_one, 3), noisy(0.04), rollout_steps=13, seed=99)
        fresh.load_state_dict(saved)
        torch.set_rng_state(rng)
        got = fresh.collect()
        assert (got == expected).all() and fresh.total_steps == col.total_steps == 78


def test_env_state_covers_plain_and_refuses_unknown_state():
    import gymnasium as gym
    import numpy as np

    from cmdp_rl.envs.env_state import env_state, load_env_state

    def make():
        return gym.wrappers.RecordEpisodeStatistics(gym.make("Pendulum-v1", max_episode_steps=30))

    a, b = make(), make()
    a.reset(seed=1)
    b.reset(seed=2)
    for _ in range(11):
        a.step(np.array([0.5], dtype=np.float32))
    load_env_state(b, env_state(a))
    for t in range(40):  # across the time limit and the reset after it
        act = np.array([np.sin(t)], dtype=np.float32)
        ra, rb = a.step(act), b.step(act)
        assert np.array_equal(ra[0], rb[0]) and ra[1:4] == rb[1:4], t
        if ra[3]:
            assert np.array_equal(a.reset()[0], b.reset()[0])
            assert ra[4]["episode"]["r"] == rb[4]["episode"]["r"]  # the wrapper's sums came back

    class World(gym.Env):
        observation_space = action_space = gym.spaces.Box(-1, 1, (1,))

        def __init__(self):
            self.world = object()  # say, a physics engine's handle

    with pytest.raises(NotImplementedError, match="World holds 'world' .* cannot resume exactly"):
        env_state(World())
