"""A fixed-seed learning run reaches a real outcome: close to the wall, without bumping it.

The naive always-forward policy gets return 0.300 at cost 97 (seed's numbers); a random initial
policy gets return near 0. PPO-Lagrangian with budget 1 must get most of the reachable progress
(the wall at 0.5 caps the return at 0.4) while keeping the evaluated cost within the budget.
"""

import json

import pytest

from cmdp_rl import load_config, train


@pytest.mark.slow  # a learning run (pyproject: markers)
def test_ppo_lagrangian_learns_to_approach_the_wall_within_budget(tmp_path):
    cfg = load_config({"algo": {"name": "ppo_lag", "cost_limit": 1.0}, "seed": 0, "total_steps": 120_000})
    result = train(cfg, tmp_path, echo=lambda s: None)
    assert result["episode_return"] >= 0.25, result
    assert result["episode_cost"] <= 1.0, result
    assert json.loads((tmp_path / "eval.json").read_text())["episodes"] == 20
