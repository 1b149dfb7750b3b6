"""CRPO (Xu, Liang, Lan 2021): the reward/cost switch on the constraint's slack, and a learning run."""

import csv

import pytest
import torch
from helpers.runs import tail_means

from cmdp_rl import Collector, keys, load_config, make_agent, make_algo, make_env, train
from cmdp_rl.algos.multiplier import EpisodeCostEstimate
from cmdp_rl.config.run_config import compose_config


def setup(algo: dict):
    # wall=pass, 3-step episodes from 0.45: most episodes cross the wall (cost 1), some do not.
    cfg = load_config(
        {
            "algo": {"name": "crpo", "update_epochs": 1, **algo},
            "rollout_steps": 32,
            "env": {"num_envs": 2, "max_steps": 3, "wall": "pass", "start": 0.45},
        }
    )
    torch.manual_seed(0)
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env)
    return make_algo(cfg.algo, agent), Collector(env, agent, cfg.rollout_steps, seed=0).collect()


def _standardized(x):
    return (x - x.mean()) / (x.std() + 1e-8)


def test_a_cost_step_is_taken_exactly_when_the_estimate_exceeds_budget_plus_tolerance():
    _, batch = setup({})
    j_c = EpisodeCostEstimate().update(batch).cost
    assert 0.3 < j_c < 1.0  # the batch's measured J_c: room to put the threshold on either side
    cases = [  # (cost_limit, tolerance, cost step?)
        (j_c - 0.1, 0.0, True),
        (j_c - 0.1, 0.05, True),
        (j_c - 0.1, 0.1, False),  # J_c == d + eta: within the tolerance, a reward step
        (j_c - 0.1, 0.2, False),
        (j_c, 0.0, False),
        (j_c + 0.1, 0.0, False),
    ]
    for limit, tol, cost_step in cases:
        algo, batch = setup({"cost_limit": limit, "tolerance": tol})
        stats = algo.update(batch)
        assert stats["cost_step"] == float(cost_step), (limit, tol, j_c)
        # The step's advantage: -A_c for a cost step, A_r otherwise (standardized, as PPO's).
        source = -batch.get(keys.COST_ADVANTAGE) if cost_step else batch.get(keys.ADVANTAGE)
        torch.testing.assert_close(batch.get(keys.POLICY_ADVANTAGE), _standardized(source))
        assert stats["lagrange_multiplier"] == 0.0


def test_cost_step_is_a_metrics_column(tmp_path):
    cfg = load_config(
        {"algo": {"name": "crpo", "cost_limit": 0.0}, "total_steps": 2048, "log_interval": 1, "env": {"wall": "pass"}}
    )
    train(cfg, tmp_path, echo=lambda s: None)
    rows = list(csv.DictReader((tmp_path / "metrics.csv").open()))
    assert rows and all(r["cost_step"] in ("0.0", "1.0") for r in rows)


def test_negative_tolerance_is_a_config_error():
    from cmdp_rl.config.validation import ConfigError

    with pytest.raises(ConfigError, match=r"^algo.tolerance must be a number >= 0, got -0.1$"):
        load_config({"algo": {"name": "crpo", "tolerance": -0.1}})


@pytest.mark.slow  # a learning run (pyproject: markers)
def test_crpo_learns_reach1d_within_budget(tmp_path):
    """Reach1D, passable wall, budget 0.5 crossings per episode. Measured on seed 0: the initial
    policy's training return is 0.00 (iteration 1); CRPO's last 10 iterations average return 0.56 at
    cost 0.48 (it alternates reward and cost steps around the budget)."""
    cfg = compose_config(
        [
            "env=reach1d_torch",
            "env.wall=pass",
            "env.num_envs=256",
            "algo=crpo",
            "algo.cost_limit=0.5",
            "algo.num_minibatches=4",
            "algo.update_epochs=5",
            "total_steps=327680",
            "log_interval=1",
            "seed=0",
        ]
    )
    train(cfg, tmp_path, echo=lambda s: None)
    rows = list(csv.DictReader((tmp_path / "metrics.csv").open()))
    ret, cost = tail_means(tmp_path, "episode_return", "episode_cost")
    assert cost <= 0.5 + 0.2, cost  # within the budget up to a margin of 0.2 (CRPO acts one batch late)
    assert ret >= 0.3 > float(rows[0]["episode_return"]) + 0.2, (ret, rows[0]["episode_return"])
    assert any(r["cost_step"] == "1.0" for r in rows) and any(r["cost_step"] == "0.0" for r in rows)
