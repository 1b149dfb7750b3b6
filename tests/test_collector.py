"""The collector keeps reward and cost apart and gets episode ends right."""

import pytest
import torch
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from torchrl.envs.utils import ExplorationType

from cmdp_rl import Collector, finished_episodes, keys
from cmdp_rl.envs import GymVecEnv, Reach1D


class ConstantPolicy(torch.nn.Module):
    def __init__(self, value):
        super().__init__()
        self.value = value

    def forward(self, obs):
        return torch.full((obs.shape[0], 1), self.value)


def policy(value):
    return TensorDictModule(ConstantPolicy(value), [keys.OBS], [keys.ACTION])


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
    assert torch.equal(nxt[keys.REWARD][0, :, 0] != 0, expected_cost.eq(0) & torch.tensor([1, 1, 1, 0, 0, 0, 0]).repeat(3)[:20].bool())
    done = nxt[keys.DONE][0, :, 0]
    assert done.nonzero().view(-1).tolist() == [6, 13]
    assert torch.equal(nxt[keys.TRUNCATED][0, :, 0], done) and not nxt[keys.TERMINATED].any()
    # the done step keeps its final observation (x = 0.4); the next step starts from the reset one
    assert abs(nxt[keys.OBS][0, 6, 0].item() - 0.4) < 1e-6 and abs(b[keys.OBS][0, 7, 0].item() - 0.1) < 1e-6
    assert b[keys.IS_INIT][0, :, 0].nonzero().view(-1).tolist() == [0, 7, 14]
    eps = finished_episodes(b)
    assert eps["cost"].tolist() == [4.0] * 6 and eps["length"].tolist() == [7.0] * 6
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
    assert finished_episodes(b)["cost"].tolist() == [1.0] * 8


def _mlp_actor_and_env(backend="gym", n=4):
    from cmdp_rl import load_config, make_agent, make_env

    cfg = load_config({"env": {"backend": backend, "num_envs": n, "max_steps": 9}})
    env = make_env(cfg.env)
    torch.manual_seed(0)
    return make_agent(cfg.policy, env).actor, cfg


@pytest.mark.parametrize("exploration", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_tensor_path_equals_the_tensordict_path(exploration):
    """The MLP actor runs on tensors (TensorActor); the batch is the one ProbabilisticActor gives."""
    from cmdp_rl import make_env
    from cmdp_rl.policies.tensor_path import TensorActor

    actor, cfg = _mlp_actor_and_env()
    assert TensorActor.wrap(actor) is not None
    batches = []
    for tensor_path in (True, False):
        torch.manual_seed(1)
        col = Collector(make_env(cfg.env), actor, 20, seed=3, exploration=exploration, tensor_path=tensor_path)
        batches.append([col.collect(), col.collect()])
    for fast, slow in zip(*batches):
        assert set(fast.keys(True, True)) == set(slow.keys(True, True))
        assert {keys.ACTION, keys.LOG_PROB, keys.LOC, keys.SCALE} <= set(fast.keys())
        for k in slow.keys(True, True):
            assert fast[k].shape == slow[k].shape and fast[k].dtype == slow[k].dtype, k
            assert torch.equal(fast[k], slow[k]), k


class CountingPolicy(TensorDictModuleBase):
    """A stateful policy: it reads its state from the root and writes the next one under "next",
    as torchrl's recurrent modules do; the state restarts at an episode start (is_init)."""

    in_keys = [keys.OBS, keys.IS_INIT, "count"]
    out_keys = [keys.ACTION, (keys.NEXT, "count")]

    def forward(self, td):
        count = td.get("count", torch.zeros(td.shape[0], 1))
        count = torch.where(td.get(keys.IS_INIT), torch.zeros_like(count), count)
        td.set(keys.ACTION, torch.full((td.shape[0], 1), 0.1))
        td.set("count", count)
        td.set((keys.NEXT, "count"), count + 1)
        return td


def test_state_written_under_next_is_carried_to_the_next_step():
    from cmdp_rl.policies.tensor_path import TensorActor

    policy = CountingPolicy()
    assert TensorActor.wrap(policy) is None  # not a stateless actor: the TensorDict path
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
        p = policy(value)
        return lambda td: p(td).set(keys.ACTION, td.get(keys.ACTION) + 0.05 * torch.randn(td.shape[0], 1))

    for make_one in (lambda: Reach1D(max_steps=9, start=[0.2, 0.45], wall="pass"),
                     lambda: gym.wrappers.RecordEpisodeStatistics(Reach1D(max_steps=9, start=[0.2, 0.45]))):
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
