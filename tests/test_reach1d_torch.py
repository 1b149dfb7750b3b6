"""The batched Reach1D: bit-for-bit the gymnasium env given the same noise; its own noise is right.

Equivalence: a noise source replays, per env, the draws each gymnasium env's ``np_random`` makes
(seeded as ``SyncVectorEnv.reset(seed=s)`` seeds env i: ``s + i``), and both envs take the same
float32 actions; every output and the true position must then be equal, across episode resets.
"""

import numpy as np
import pytest
import torch
from gymnasium.utils import seeding
from helpers.policies import ForwardPolicy

from cmdp_rl import Collector, ConfigError, keys, load_config, make_env, train
from cmdp_rl.envs import GymVecEnv, Reach1D, TorchReach1D


class GymDraws:
    """A :class:`~cmdp_rl.envs.reach1d.batched.TorchNoise` drawing, env by env, from the generators
    gymnasium's vector env would give its sub-envs: only the envs in ``where`` consume a draw."""

    def __init__(self, num_envs):
        self.num_envs = num_envs
        self.rngs = None

    def seed(self, seed):
        self.rngs = [seeding.np_random(seed + i)[0] for i in range(self.num_envs)]

    def _draw(self, where, fn):
        ids = range(self.num_envs) if where is None else where.nonzero().view(-1).tolist()
        out = torch.full((self.num_envs,), float("nan"), dtype=torch.float64)
        for i in ids:
            out[i] = fn(self.rngs[i])
        return out

    def normal(self, where):
        return self._draw(where, lambda r: r.standard_normal())

    def uniform(self, where):
        return self._draw(where, lambda r: r.random())


OPTIONS = [
    {},  # the seed's task
    {"wall": "pass", "max_steps": 12},
    {"start": [0.3, 0.6], "max_steps": 9, "obs_noise": 0.1},
    {"probe": True, "wall": "pass", "start": [0.0, 1.0], "max_steps": 15, "goal": 0.7, "wall_x": 0.4},
    {"obs_noise": 0.0, "max_steps": 7},
]


# Two implementations compared exactly: each step is elementwise float64 +, -, *, abs and clamping in the same order
# on both sides, each correctly rounded whatever kernel runs it, so the equality holds on any IEEE 754 CPU (and
# under every make test-cpus setting).
@pytest.mark.cpu_kernels
@pytest.mark.parametrize("options", OPTIONS)
def test_matches_gymnasium_step_for_step_with_the_same_noise(options):
    n, seed, steps = 5, 11, 210
    gym_env = GymVecEnv(lambda: Reach1D(**options), n)
    torch_env = TorchReach1D(n, **options, noise=GymDraws(n))
    infos = []
    vec_step = gym_env.envs.step
    gym_env.envs.step = lambda a: (out := vec_step(a)) and infos.append(out[4]) or out  # keep each info
    rng = np.random.default_rng(3)
    assert torch.equal(gym_env.reset(seed=seed), torch_env.reset(seed=seed))
    assert torch_env.x.tolist() == [e.unwrapped.x for e in gym_env.envs.envs]
    ends = 0
    for t in range(steps):
        # Random float32 actions beyond the bounds, and pushes at the bound that bump the wall.
        a = rng.uniform(-0.15, 0.15, size=(n, torch_env.action_dim)).astype(np.float32)
        a[: n // 2, 0] = np.float32(0.1) if t % 20 < 12 else a[: n // 2, 0]
        if torch_env.probe:
            a[:, 1] = rng.uniform(-1.5, 1.5, size=n).astype(np.float32)
        action = torch.from_numpy(a)
        g, s = gym_env.step(action), torch_env.step(action)
        for name in g._fields:
            assert getattr(g, name).dtype == getattr(s, name).dtype, name
            assert torch.equal(getattr(g, name), getattr(s, name)), (t, name, getattr(g, name), getattr(s, name))
        # true x: after the move (gymnasium's info["true_x"], final_info's at an episode end) ...
        done = (g.terminated | g.truncated).view(-1)
        ends += int(done.sum())
        true_x = np.array(infos[-1]["true_x"], dtype=np.float64)
        if done.any():
            true_x[done.numpy()] = infos[-1]["final_info"]["true_x"][done.numpy()]
        assert torch_env.final_x.tolist() == true_x.tolist()
        # ... and the state the next step starts from, reset where the episode ended.
        assert torch_env.x.tolist() == [e.unwrapped.x for e in gym_env.envs.envs]
        assert torch.equal(torch_env.final_x[~done], torch_env.x[~done])
    assert ends >= n  # resets were exercised


def test_final_x_is_the_position_before_reset():
    env = TorchReach1D(3, max_steps=2, obs_noise=0.0)
    env.reset(seed=0)
    env.step(torch.full((3, 1), 0.1))
    env.step(torch.full((3, 1), 0.1))  # truncated: x reset to the start
    assert env.x.tolist() == [0.1] * 3
    assert env.final_x.tolist() == [0.1 + 2 * float(np.float32(0.1))] * 3


def test_float64_action_cannot_hit_the_wall_edge():
    """Actions of exactly 0.1 in float64 are cast to the float32 bound first, as in gymnasium:
    the effector never lands on x = 0.5 and stays behind the wall."""
    env = TorchReach1D(1, obs_noise=0.0)
    env.reset(seed=0)
    costs = [env.step(torch.full((1, 1), 0.1, dtype=torch.float64)).cost.item() for _ in range(8)]
    assert costs == [0.0, 0.0, 0.0] + [1.0] * 5 and env.x.item() == 0.1 + 3 * float(np.float32(0.1))


def test_own_noise_statistics_and_seeding():
    n = 200_000
    env = TorchReach1D(n, start=[0.2, 0.6], obs_noise=0.05)
    obs = env.reset(seed=7)
    x = env.x
    assert abs(x.mean().item() - 0.4) < 2e-3 and abs(x.std().item() - 0.4 / 12**0.5) < 2e-3
    assert x.min().item() >= 0.2 and x.max().item() < 0.6
    # Uniform: each tenth of the range holds a tenth of the starts.
    hist = torch.histc(x, bins=10, min=0.2, max=0.6) / n
    assert (hist - 0.1).abs().max().item() < 5e-3
    err = obs[:, 0].double() - x  # readings are x + N(0, 0.05^2); clipping cannot act from [0.2, 0.6]
    assert abs(err.mean().item()) < 1e-3 and abs(err.std().item() - 0.05) < 1e-3
    assert abs(((err / 0.05) ** 3).mean().item()) < 0.03  # symmetric
    assert abs(((err / 0.05) ** 4).mean().item() - 3.0) < 0.06  # Gaussian kurtosis
    # A step: readings of the new position, same law; probe readings with half the noise.
    step = env.step(torch.zeros(n, 1))
    err = step.next_obs[:, 0].double() - env.final_x
    assert abs(err.mean().item()) < 1e-3 and abs(err.std().item() - 0.05) < 1e-3
    probe = TorchReach1D(n, start=0.5, obs_noise=0.05, probe=True)
    probe.reset(seed=1)
    s = probe.step(torch.tensor([[0.1, 1.0]]).expand(n, 2))
    err = s.next_obs[:, 0].double() - 0.5
    assert abs(err.std().item() - 0.025) < 5e-4 and torch.equal(s.next_obs[:, 2], s.next_obs[:, 0])
    # Seeding: same seed, same draws; another seed, others.
    a = TorchReach1D(4, start=[0.0, 1.0]).reset(seed=3)
    b = TorchReach1D(4, start=[0.0, 1.0]).reset(seed=3)
    c = TorchReach1D(4, start=[0.0, 1.0]).reset(seed=4)
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_make_env_and_collector_on_the_batched_env():
    cfg = load_config({"env": {"backend": "torch", "num_envs": 16, "max_steps": 10}})
    env = make_env(cfg.env)
    assert isinstance(env, TorchReach1D) and env.num_envs == 16

    b = Collector(
        env, ForwardPolicy(lambda obs: torch.full((obs.shape[0], 1), 0.1)), rollout_steps=25, seed=0
    ).collect()
    assert b.batch_size == torch.Size([16, 25])
    done = b[keys.NEXT][keys.DONE][:, :, 0]
    assert done[:, 9].all() and done[:, 19].all() and done.sum().item() == 32
    assert b[keys.IS_INIT][:, 10, 0].all()
    # pushing at the bound: 3 moves, then the wall: cost 7 per 10-step episode
    assert b[keys.NEXT][keys.EPISODE_COST][:, 9, 0].eq(7.0).all()


def test_train_runs_on_the_batched_env(tmp_path):
    cfg = load_config(
        {
            "env": {"backend": "torch", "num_envs": 64},
            "total_steps": 64 * 32 * 2,
            "rollout_steps": 32,
            "eval_episodes": 4,
            "algo": {"name": "ppo_lag", "update_epochs": 2, "num_minibatches": 4},
        }
    )
    result = train(cfg, tmp_path, echo=lambda s: None)
    assert result["episodes"] == 4 and result["steps"] == 4096
    assert (tmp_path / "metrics.csv").read_text().count("\n") == 3  # header + 2 iterations


def test_bad_backend_named():
    from cmdp_rl import ConfigError

    with pytest.raises(ConfigError, match="env.backend must be one of"):
        load_config({"env": {"backend": "jax"}})


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message on a machine without CUDA")
def test_cuda_requested_without_cuda_is_a_config_error():
    from cmdp_rl import ConfigError

    with pytest.raises(ConfigError, match="device must be cpu on this machine"):
        load_config({"device": "cuda", "env": {"backend": "torch"}})


def test_stagger_spreads_the_first_episode_ends():
    env = TorchReach1D(4096, max_steps=10, obs_noise=0.0, stagger=True)
    env.reset(seed=0)
    first_end = torch.full((4096,), -1)
    for t in range(10):
        s = env.step(torch.zeros(4096, 1))
        first_end[(first_end < 0) & s.truncated.view(-1)] = t
    counts = torch.bincount(first_end, minlength=10)
    assert (first_end >= 0).all() and (counts - 409.6).abs().max() < 80  # uniform over the 10 steps
    # later episodes are whole: the next time limit comes exactly max_steps after the first
    for t in range(10):
        s = env.step(torch.zeros(4096, 1))
        assert torch.equal(s.truncated.view(-1), first_end == t)
    with pytest.raises(ConfigError, match="env.stagger must be false unless env.backend=torch"):
        load_config({"env": {"stagger": True}})


def test_state_dict_resumes_the_same_trajectories():
    """Resume: a collector on a fresh TorchReach1D restored from state_dict() collects what the
    original would have (positions, step counters, probe readings, the generator's state)."""
    from cmdp_rl.policies import make_agent
    from cmdp_rl.policies.mlp import PolicyConfig

    def build():
        env = TorchReach1D(6, max_steps=7, start=[0.0, 0.8], probe=True, stagger=True)
        torch.manual_seed(0)
        return env, make_agent(PolicyConfig(), env)

    env, actor = build()
    col = Collector(env, actor, 10, seed=5)
    col.collect()
    state = col.state_dict()
    rng = torch.get_rng_state()
    expected = col.collect()
    env2, actor2 = build()
    col2 = Collector(env2, actor2, 10, seed=99)  # another seed: everything must come from the state
    col2.load_state_dict(state)
    torch.set_rng_state(rng)
    got = col2.collect()
    for k in expected.keys(True, True):
        assert torch.equal(expected[k], got[k]), k
