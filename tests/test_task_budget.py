"""The budget belongs to the task: ``algo.cost_limit`` defaults to the env's budget (d = 25 on the
Safety-Gymnasium and velocity tasks, 1 on Reach1D) for every registered algorithm, with no file per
(env, algo) pair; a value given wins; the budget in force is printed and kept in config.yaml.
And ``env.cost_names`` names a third-party env's costs."""

import json

import pytest
import yaml
from helpers.cli import train_py
from helpers.cost_envs import TWO_COST_ID as ENV_ID

from cmdp_rl import load_config, train
from cmdp_rl.config.registry import component, names
from cmdp_rl.config.run_config import CONFIG_DIR, compose_config
from cmdp_rl.config.validation import ConfigError

TASK_BUDGETS = {"safe_nav": 25.0, "safety_gym": 25.0, "velocity": 25.0, "reach1d": 1.0, "reach1d_torch": 1.0}


def budget_of(env: str, algo: str, *overrides: str) -> object:
    """``algo.cost_limit`` as ``train.py env=<env> algo=<algo>`` composes it; an algorithm without
    a yaml (one registered by a test file) is built from its options' defaults."""
    if (CONFIG_DIR / "algo" / f"{algo}.yaml").is_file():
        return compose_config([f"env={env}", f"algo={algo}", *overrides]).algo.cost_limit
    env_name = "reach1d" if env == "reach1d_torch" else env
    return load_config({"env": {"name": env_name}, "algo": {"name": algo}}).algo.cost_limit


@pytest.mark.parametrize("env", sorted(TASK_BUDGETS))
def test_every_registered_algorithm_runs_at_the_tasks_budget(env):
    takes = [a for a in names("algo") if component("algo", a).options.envs in (None, (env,))]
    wrong = {a: budget_of(env, a) for a in takes if budget_of(env, a) != TASK_BUDGETS[env]}
    assert not wrong, f"env={env}: budgets other than the task's {TASK_BUDGETS[env]}: {wrong}"


def test_no_tuning_file_sets_only_a_budget():
    for path in sorted((CONFIG_DIR / "tuning").rglob("*.yaml")):
        algo = (yaml.safe_load(path.read_text()) or {}).get("algo", {}) or {}
        assert "cost_limit" not in algo, f"{path}: the budget is the task's (env options' budget())"


def test_a_given_budget_wins_and_grid_budgets_follow_its_costs():
    assert budget_of("safe_nav", "focops", "algo.cost_limit=3") == 3.0
    assert budget_of("grid", "ppo_lag") == [0.3, 0.15]
    assert budget_of("grid", "cpo", "env.costs=[hazard_b]") == [0.15]


def test_the_budget_in_force_is_printed_and_kept_in_config_yaml(tmp_path):
    cfg = load_config(
        {
            "env": {"name": "reach1d", "num_envs": 2, "max_steps": 10},
            "algo": {"name": "ppo_lag", "update_epochs": 1, "num_minibatches": 1},
            "rollout_steps": 8,
            "total_steps": 16,
            "eval_episodes": 1,
        }
    )
    lines: list[str] = []
    train(cfg, tmp_path, echo=lines.append)
    assert "cost limit 1.0 (the task's)" in lines[0]
    assert yaml.safe_load((tmp_path / "config.yaml").read_text())["algo"]["cost_limit"] == 1.0


def _cost_vector_cfg(**env) -> dict:
    return {
        "env": {"name": "gym", "id": ENV_ID, "num_envs": 2, "kwargs": {"length": 4, "named": False}, **env},
        "algo": {"name": "ppo_lag", "update_epochs": 1, "num_minibatches": 1},
        "rollout_steps": 8,
        "total_steps": 16,
        "eval_episodes": 2,
    }


def test_env_cost_names_name_a_gym_envs_costs_in_metrics_and_eval(tmp_path):
    train(load_config(_cost_vector_cfg(cost_names=["hazard", "speed"])), tmp_path, echo=lambda _: None)
    header = (tmp_path / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"episode_cost/hazard", "episode_cost/speed"} <= set(header)
    assert not [c for c in header if "cost_0" in c or "cost_1" in c]
    result = json.loads((tmp_path / "eval.json").read_text())
    assert {"episode_cost/hazard", "episode_cost/speed", "cost_limit/speed"} <= set(result)


def test_env_cost_names_of_the_wrong_count_stop_before_any_output(tmp_path):
    with pytest.raises(ConfigError, match=r"env.cost_names must name the 2 cost\(s\)"):
        train(load_config(_cost_vector_cfg(cost_names=["hazard"])), tmp_path / "run", echo=lambda _: None)
    assert not (tmp_path / "run").exists()
    with pytest.raises(ConfigError, match="env.cost_names must be a non-empty list of distinct names"):
        load_config(_cost_vector_cfg(cost_names=["a", "a"]))


def test_train_cli_takes_env_cost_names_and_refuses_a_wrong_count_in_one_line(tmp_path):
    proc = train_py(
        "env=gym",
        f"env.id=helpers.cost_envs:{ENV_ID}",
        "env.cost_names=[hazard,speed,heat]",
        f"hydra.run.dir={tmp_path / 'run'}",
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr + proc.stdout
    assert proc.stderr.strip().splitlines()[-1] == (
        f"config error: env.cost_names must name the 2 cost(s) helpers.cost_envs:{ENV_ID} reports, got 3: ['hazard', 'speed', 'heat']"
    )
    assert not (tmp_path / "run" / "metrics.csv").exists()
