"""env=grid: the registered gridworld through load_config and train() (discrete actions, K = 2)."""

import csv

import pytest

from cmdp_rl import load_config, train
from cmdp_rl.config.validation import ConfigError
from cmdp_rl.envs import make_env


def test_grid_env_builds_with_discrete_actions_and_two_named_costs():
    cfg = load_config({"env": {"name": "grid", "num_envs": 2}})
    env = make_env(cfg.env)
    try:
        assert env.cost_names == ("hazard_a", "hazard_b") and env.action_space.n == 4
        assert env.obs_dim == 31  # one-hot over the default grid's open cells (6 x 7 minus 11 walls)
    finally:
        env.close()


def test_grid_costs_option_reports_a_subset_of_the_hazards_in_order():
    import torch

    envs = [
        make_env(load_config({"env": {"name": "grid", "num_envs": 4, "costs": c}}).env)
        for c in (["hazard_a", "hazard_b"], ["hazard_b"])
    ]
    try:
        assert envs[1].cost_names == ("hazard_b",) and envs[1].num_costs == 1
        for env in envs:
            env.reset(seed=3)
        torch.manual_seed(0)
        for _ in range(40):  # the same seeds and actions: the K = 1 variant's cost is the K = 2 env's column
            action = torch.randint(0, 4, (4, 1))
            both, one = (env.step(action).cost for env in envs)
            assert torch.equal(one, both[:, 1:])
    finally:
        for env in envs:
            env.close()
    with pytest.raises(ConfigError, match=r"^env.costs must be a non-empty list of distinct names"):
        load_config({"env": {"name": "grid", "costs": ["hazard_a", "hazard_a"]}})


def test_grid_bad_layout_is_a_one_line_config_error():
    with pytest.raises(ConfigError, match="^env.layout: "):
        load_config({"env": {"name": "grid", "layout": ["S..", ".x.", "..G"]}})


def test_ppo_lag_trains_on_grid_with_a_budget_per_hazard(tmp_path, quiet):
    cfg = load_config(
        {
            "env": {"name": "grid", "num_envs": 2},
            "algo": {"name": "ppo_lag", "cost_limit": [0.3, 0.15]},
            "rollout_steps": 64,
            "total_steps": 2 * 128,
            "eval_episodes": 4,
            "log_interval": 1,
        }
    )
    result = train(cfg, tmp_path / "run", echo=quiet)
    with open(tmp_path / "run" / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and rows[0]["cost_limit/hazard_b"] == "0.15"
    assert result["cost_limit/hazard_a"] == 0.3 and "violation_rate/hazard_b" in result


def test_a_trained_policy_is_valued_exactly_against_the_lp():
    """analysis/grid_policy.py: the network's action probabilities in every state, valued by one
    linear solve. A network whose logits are zero is the uniform policy; one whose logits pick a
    move per cell is that deterministic policy."""
    import numpy as np
    import torch

    from cmdp_rl.envs.grid.optimum import solve_constrained
    from cmdp_rl.envs.grid.tabular import evaluate, grid_cmdp
    from cmdp_rl.policies import make_agent
    from lab.studies.grid_policy import exact_gap, policy_table

    cfg = load_config({"env": {"name": "grid", "num_envs": 2}, "policy": {"name": "mlp", "hidden_sizes": [8]}})
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env)
    env.close()
    cmdp = grid_cmdp()
    out = agent.actor.head.net[-1]  # the last linear layer: its bias alone sets the logits once the weight is 0
    with torch.no_grad():
        out.weight.zero_()
        out.bias.zero_()
    assert np.allclose(policy_table(agent, cmdp), 0.25)
    best = solve_constrained(cmdp, (0.3, 0.15))
    uniform = evaluate(cmdp, np.full((cmdp.num_states, 4), 0.25))
    gap = exact_gap(agent, cmdp, best)
    assert gap.ret == pytest.approx(uniform.ret) and gap.costs == pytest.approx(tuple(uniform.costs))
    assert gap.gap == pytest.approx((best.ret - uniform.ret) / best.ret)
    with torch.no_grad():
        out.bias.copy_(torch.tensor([0.0, 30.0, 0.0, 0.0]))  # always right: along the middle row
    right = evaluate(cmdp, np.tile([0.0, 1.0, 0.0, 0.0], (cmdp.num_states, 1)))
    gap = exact_gap(agent, cmdp, best)
    assert gap.ret == pytest.approx(right.ret, abs=1e-9) and not gap.within_budgets  # hazard_a 0.8 > 0.3
    env = make_env(cfg.env)
    lstm = make_agent(load_config({"env": {"name": "grid", "num_envs": 2}, "policy": {"name": "lstm"}}).policy, env)
    env.close()
    with pytest.raises(ValueError, match="only a memoryless policy is a table"):
        policy_table(lstm, cmdp)
