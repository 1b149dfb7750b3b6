"""Observation normalization and reward/cost scaling: the statistics, their use, their saving."""

import json

import numpy as np
import pytest
import torch

from cmdp_rl import ConfigError, keys, load_config, make_agent, make_algo, make_env, train
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.rollout.normalization import Normalizers, ObservationNormalizer, ReturnScaler, make_normalizers
from cmdp_rl.run.checkpoint import load_checkpoint, save_checkpoint
from cmdp_rl.run.evaluation import evaluate


def test_normalized_observations_have_zero_mean_unit_std_on_a_known_stream():
    gen = torch.Generator().manual_seed(0)
    mean = torch.tensor([5.0, -3.0, 100.0, 0.0])
    std = torch.tensor([2.0, 0.5, 10.0, 1e-3])
    norm = ObservationNormalizer(4, clip=10.0)
    seen = []
    for _ in range(20):  # in batches of [num_envs, T, obs_dim], as the collector delivers them
        x = mean + std * torch.randn(8, 64, 4, generator=gen)
        norm.update(x)
        seen.append(x.reshape(-1, 4))
    seen = torch.cat(seen).double()
    # the running statistics are those of all the data (Welford's parallel combination)
    assert torch.allclose(norm.stats.mean.double(), seen.mean(0), rtol=1e-5, atol=1e-6)
    assert torch.allclose(norm.stats.var.double(), seen.var(0, unbiased=False), rtol=1e-3)
    fresh = mean + std * torch.randn(20_000, 4, generator=gen)
    z = norm(fresh)
    assert z.mean(0).abs().max() < 0.03 and (z.std(0) - 1).abs().max() < 0.03
    assert norm(torch.tensor([[1e6, 0.0, 0.0, 0.0]]))[0, 0] == 10.0  # clipped


def test_return_scaler_divides_by_the_std_of_the_discounted_sums():
    gamma = 0.9
    signal = torch.tensor([[1.0, 0.0, 2.0, 1.0, 0.0], [0.0, 3.0, 0.0, 0.0, 1.0]]).unsqueeze(-1)
    done = torch.tensor([[False, False, True, False, False], [False, False, False, False, False]]).unsqueeze(-1)
    scaler = ReturnScaler(num_envs=2, gamma=gamma)
    scaler.update(signal, done)
    expected = []  # by hand: R_t = gamma R_{t-1} + x_t, reset after a done step
    for env in range(2):
        r = 0.0
        for t in range(5):
            r = gamma * r + signal[env, t, 0].item()
            expected.append(r)
            r = 0.0 if done[env, t, 0] else r
    var = np.var(expected)
    assert scaler.stats.var.item() == pytest.approx(var, rel=1e-3)
    assert torch.allclose(scaler.scale(signal), signal / var**0.5, rtol=1e-3)
    # the sums carry over into the next batch; env 0's episode restarted at t=3
    assert scaler.running_return[:, 0].tolist() == pytest.approx([gamma * 1.0 + 0.0, expected[-1]])


def _reach1d_cfg(**normalize):
    return load_config(
        {
            "env": {"num_envs": 2},
            "rollout_steps": 32,
            "normalize": normalize,
            "algo": {"name": "ppo_lag", "update_epochs": 1, "num_minibatches": 2},
        }
    )


def test_statistics_survive_save_and_load(tmp_path):
    cfg = _reach1d_cfg(obs=True, reward=True, cost=True)
    env = make_env(cfg.env)
    ac = make_agent(cfg.policy, env, make_normalizers(cfg, env))
    algo = make_algo(cfg.algo, ac)
    batch = Collector(env, ac, cfg.rollout_steps, seed=0).collect()
    ac.normalizers.scale_batch(batch)
    algo.update(batch)
    ac.normalizers.update_observation_stats(batch)
    save_checkpoint(tmp_path / "c.pt", {"algo_state": algo.state_dict()})

    fresh = make_agent(cfg.policy, env, make_normalizers(cfg, env))
    make_algo(cfg.algo, fresh).load_state_dict(load_checkpoint(tmp_path / "c.pt")["algo_state"])
    for name in ("obs", "reward", "cost"):
        a, b = getattr(ac.normalizers, name), getattr(fresh.normalizers, name)
        assert (
            a.stats.count.item() > 1
            and torch.equal(a.stats.mean, b.stats.mean)
            and torch.equal(a.stats.var, b.stats.var)
        )
    # the networks of the loaded copy normalize with the loaded statistics: the same outputs
    probe = {keys.OBS: torch.tensor([[0.3, 0.9], [0.7, 0.9]])}
    with torch.no_grad():
        for signal in ("reward", "cost"):
            assert torch.equal(ac.value(signal, probe), fresh.value(signal, probe))
        assert torch.equal(ac.actor.params(probe)[keys.LOC], fresh.actor.params(probe)[keys.LOC])
        # ... which are not those of fresh statistics
        unloaded = make_agent(cfg.policy, env, make_normalizers(cfg, env))
        unloaded.load_state_dict({k: v for k, v in fresh.state_dict().items() if ".stats." not in k}, strict=False)
        assert not torch.equal(ac.value("reward", probe), unloaded.value("reward", probe))
    # one shared normalizer instance sits in front of all three networks
    assert fresh.normalizers.obs is not None
    assert (
        fresh.actor.body.prep
        is fresh.normalizers.obs
        is fresh.critics["reward"].body.prep
        is fresh.critics["cost"].body.prep
    )


def test_training_updates_statistics_from_collected_data_and_evaluation_leaves_them(tmp_path):
    cfg = load_config(
        {
            "env": {"num_envs": 2},
            "rollout_steps": 32,
            "total_steps": 128,
            "eval_episodes": 2,
            "normalize": {"obs": True},
            "algo": {"name": "ppo", "update_epochs": 1, "num_minibatches": 2},
        }
    )
    train(cfg, tmp_path, echo=lambda _: None)
    env = make_env(cfg.env)
    ac = make_agent(cfg.policy, env, make_normalizers(cfg, env))
    make_algo(cfg.algo, ac).load_state_dict(load_checkpoint(tmp_path / "checkpoint.pt")["members"][0]["algo_state"])
    stats = ac.normalizers.obs.stats
    # one observation per collected step, nothing from evaluation
    assert stats.count.item() == pytest.approx(128 + 1e-4)
    assert stats.mean[1].item() == pytest.approx(0.9)  # Reach1D's second observation is the goal, 0.9
    assert stats.var[1].item() < 1e-5  # (the prior of count 1e-4, var 1 leaves ~1e-6)
    assert 0 < stats.mean[0].item() < 1
    before = {k: v.clone() for k, v in ac.normalizers.state_dict().items()}
    evaluate(ac, make_env(cfg.env), episodes=2)
    assert all(torch.equal(before[k], v) for k, v in ac.normalizers.state_dict().items())
    assert json.loads((tmp_path / "eval.json").read_text())["episodes"] == 2


def test_off_by_default_and_nothing_extra_in_the_checkpoint():
    cfg = load_config({})
    assert not (cfg.normalize.obs or cfg.normalize.reward or cfg.normalize.cost)
    env = make_env(cfg.env)
    ac = make_agent(cfg.policy, env, make_normalizers(cfg, env))
    assert not any(k.startswith("normalizers") for k in ac.state_dict())
    assert isinstance(ac.normalizers, Normalizers) and ac.normalizers.obs is None


@pytest.mark.parametrize(
    "override,field",
    [
        ({"normalize": {"obs_clip": 0.0}}, "normalize.obs_clip"),
        ({"normalize": {"cost": True}, "algo": {"name": "penalty"}}, "normalize.cost"),
        ({"normalize": {"scale": True}}, "normalize"),
    ],
)
def test_normalize_config_errors_name_the_field(override, field):
    with pytest.raises(ConfigError) as err:
        load_config(override)
    assert str(err.value).startswith(field), str(err.value)
