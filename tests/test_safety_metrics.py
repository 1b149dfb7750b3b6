"""The field's metrics: cost rate over training, Safety Gym's normalized return / violation / cost rate."""

import csv
import json

import pytest
import torch
from helpers.policies import ForwardPolicy

from cmdp_rl import Collector, ConfigError, keys, load_config, train
from cmdp_rl.envs import GymVecEnv, Reach1D
from cmdp_rl.report.safety_metrics import EPSILON, Reference, normalized_scores


def test_normalized_scores_follow_safety_gym():
    ref = Reference(episode_return=200.0, episode_cost=85.0, cost_rate=0.08)
    s = normalized_scores(150.0, 40.0, 0.02, cost_limit=25.0, ref=ref)
    assert s["normalized_return"] == pytest.approx(0.75)
    assert s["normalized_violation"] == pytest.approx((40 - 25) / (85 - 25))
    assert s["normalized_cost_rate"] == pytest.approx(0.25)
    # within budget: no violation, whatever PPO did
    assert normalized_scores(150.0, 20.0, 0.02, 25.0, ref)["normalized_violation"] == 0.0
    # PPO itself within budget: the denominator is Safety Gym's epsilon
    within = Reference(200.0, 10.0, 0.01)
    assert normalized_scores(1.0, 26.0, 0.0, 25.0, within)["normalized_violation"] == pytest.approx(1.0 / EPSILON)
    # unknown reference numbers leave their metric blank
    assert normalized_scores(1.0, 1.0, 0.1, 25.0, None) == dict.fromkeys(
        ["normalized_return", "normalized_violation", "normalized_cost_rate"]
    )
    partial = normalized_scores(1.0, 1.0, 0.1, 25.0, Reference(episode_return=2.0))
    assert partial == {"normalized_return": 0.5, "normalized_violation": None, "normalized_cost_rate": None}


def test_collector_counts_every_cost_it_collects():
    # Reach1D pushed at the bound: 4 wall bumps per 7-step episode (tests/test_collector.py)
    env = GymVecEnv(lambda: Reach1D(max_steps=7, obs_noise=0.0), 3)
    actor = ForwardPolicy(lambda obs: torch.full((obs.shape[0], 1), 0.1))
    col = Collector(env, actor, rollout_steps=14, seed=0)
    sums = [col.collect()[keys.NEXT][keys.COST].sum().item() for _ in range(3)]
    assert col.total_cost == sum(sums) == 3 * 3 * 2 * 4 and col.total_steps == 126


SHORT = {
    "env": {"num_envs": 2},
    "rollout_steps": 32,
    "total_steps": 128,
    "eval_episodes": 2,
    "algo": {"name": "ppo", "update_epochs": 1, "num_minibatches": 2},
}


def _rows(path):
    return list(csv.DictReader(open(path / "metrics.csv")))


def test_cost_rate_is_reported_every_iteration_and_normalized_columns_stay_blank(tmp_path):
    # starting next to the wall, the untrained policy bumps it now and then
    result = train(load_config({**SHORT, "env": {"num_envs": 2, "start": 0.45}}), tmp_path, echo=lambda _: None)
    rows = _rows(tmp_path)
    total = 0.0
    for row in rows:
        step_cost = float(row["cost_rate"]) * int(row["step"]) - total
        assert step_cost >= -1e-6 and abs(step_cost - round(step_cost)) < 1e-6  # Reach1D costs are 0 or 1
        total += step_cost
        assert row["normalized_return"] == row["normalized_violation"] == row["normalized_cost_rate"] == ""
    assert total >= 5
    ev = json.loads((tmp_path / "eval.json").read_text())
    assert ev["cost_rate"] == pytest.approx(float(rows[-1]["cost_rate"])) == result["cost_rate"]
    assert ev["normalized_return"] is None and ev["normalized_violation"] is None and ev["reference"] is None


def test_a_reference_run_normalizes_the_metrics(tmp_path):
    ref_dir, run_dir = tmp_path / "ppo", tmp_path / "lag"
    ref = train(load_config(SHORT), ref_dir, echo=lambda _: None)
    messages = []
    cfg = load_config(
        {
            **SHORT,
            "algo": {**SHORT["algo"], "name": "ppo_lag", "cost_limit": 0.5},
            "seed": 1,
            "reference": {"run": str(ref_dir)},
        }
    )
    ev = train(cfg, run_dir, echo=messages.append)
    assert not [m for m in messages if m.startswith("warning")]
    assert ev["reference"] == {
        "episode_return": ref["episode_return"],
        "episode_cost": ref["episode_cost"],
        "cost_rate": ref["cost_rate"],
        "source": str(ref_dir),
    }
    expected = normalized_scores(
        ev["episode_return"],
        ev["episode_cost"],
        ev["cost_rate"],
        0.5,
        Reference(ref["episode_return"], ref["episode_cost"], ref["cost_rate"]),
    )
    assert {k: ev[k] for k in expected} == expected
    for row in _rows(run_dir):
        if row["episode_return"] != "nan":
            assert float(row["normalized_return"]) == pytest.approx(
                float(row["episode_return"]) / ref["episode_return"]
            )
        assert float(row["normalized_cost_rate"]) == pytest.approx(float(row["cost_rate"]) / ref["cost_rate"])


def test_reference_numbers_and_warnings(tmp_path):
    ref_dir = tmp_path / "ref"
    train(load_config({**SHORT, "algo": {**SHORT["algo"], "name": "ppo_lag"}}), ref_dir, echo=lambda _: None)
    messages = []
    train(
        load_config({**SHORT, "total_steps": 64, "reference": {"run": str(ref_dir)}}),
        tmp_path / "run",
        echo=messages.append,
    )
    warnings = [m for m in messages if m.startswith("warning")]
    assert len(warnings) == 2 and "algo=ppo_lag" in warnings[0] and "128 steps" in warnings[1]
    ev = train(load_config({**SHORT, "reference": {"episode_return": 2.0}}), tmp_path / "numbers", echo=lambda _: None)
    assert ev["normalized_return"] == pytest.approx(ev["episode_return"] / 2.0)
    assert ev["normalized_violation"] is None and ev["normalized_cost_rate"] is None


def test_bad_references_are_refused_before_training(tmp_path):
    ref_dir = tmp_path / "ref"
    train(load_config(SHORT), ref_dir, echo=lambda _: None)
    for override, message in (
        ({"run": str(tmp_path / "nowhere")}, "reference.run must be a finished run's directory"),
        ({"run": str(ref_dir), "episode_return": 1.0}, "reference must be either reference.run"),
        ({"episode_return": 0.0}, "reference.episode_return"),
        ({"cost_rate": -0.1}, "reference.cost_rate"),
    ):
        with pytest.raises(ConfigError, match=message):
            load_config({**SHORT, "reference": override})
    with pytest.raises(ConfigError, match="reference.run must be a usable reference run, but it ran another env"):
        load_config({**SHORT, "env": {"num_envs": 2, "wall": "pass"}, "reference": {"run": str(ref_dir)}})
