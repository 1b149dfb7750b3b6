"""Env presets and their tuning files (configs/tuning/): what they set, for which algorithm or
policy, and that the batched Reach1D preset reaches the foundation issue's quality on its budget."""

import pytest

from cmdp_rl import train
from cmdp_rl.config.registry import names
from cmdp_rl.config.run_config import CONFIG_DIR, compose_config
from cmdp_rl.config.validation import ConfigError

ALGOS = ["ppo", "penalty", "ppo_lag", "pid_lag", "cpo"]
POLICIES = ["mlp", "lstm", "gru", "transformer"]


# Every registered algorithm with a yaml of its own (a test file's registered toy has none).
REGISTERED = [a for a in names("algo") if (CONFIG_DIR / "algo" / f"{a}.yaml").is_file()]


@pytest.mark.parametrize("env", ["reach1d", "reach1d_torch", "grid", "fork", "safe_nav", "safety_gym", "velocity"])
@pytest.mark.parametrize("algo", REGISTERED)
def test_every_registered_algorithm_composes_with_every_env_preset(algo, env):
    try:
        cfg = compose_config([f"env={env}", f"algo={algo}"])
    except ConfigError as exc:  # a pairing the algorithm cannot take says so in one line, naming a field
        assert "\n" not in str(exc) and str(exc).startswith(("algo", "env", "policy")), exc
        return
    assert cfg.algo.name == algo and cfg.algo.cost_limit is not None


@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("policy", POLICIES)
def test_the_batched_preset_composes_with_every_algorithm_and_policy(algo, policy):
    # The preset once set algo.lr in the env file, and CPO has no such field: a config error.
    cfg = compose_config(["env=reach1d_torch", f"algo={algo}", f"policy={policy}"])
    assert cfg.env.backend == "torch" and cfg.env.num_envs == 1024
    assert cfg.algo.name == algo and cfg.policy.name == policy


def test_tuning_files_reach_only_their_own_pair():
    lag = compose_config(["env=reach1d_torch"])  # ppo_lag and mlp: both tuning files apply
    assert (lag.algo.lr, lag.algo.critic_lr, lag.algo.multiplier.init) == (2e-3, 3e-3, 0.3)
    assert (lag.policy.hidden_sizes, lag.policy.init_log_std) == ([32, 32], -1.5)
    ppo = compose_config(["env=reach1d_torch", "algo=ppo"])  # the PPO family's rates, no lambda
    assert (ppo.algo.lr, ppo.algo.critic_lr) == (1e-3, 3e-3)
    lstm = compose_config(["env=reach1d_torch", "policy=lstm"])  # the MLP's tuning stays with the MLP
    assert lstm.policy.init_log_std == -0.5
    gym = compose_config(["env=reach1d"])  # the gym env has no tuning files: the groups' own defaults
    assert (gym.algo.lr, gym.algo.multiplier.init, gym.policy.hidden_sizes) == (3e-4, 0.01, [64, 64])


def test_the_grid_preset_evaluates_the_stochastic_policy_and_every_algorithm_gets_its_budgets():
    lag = compose_config(["env=grid", "algo=ppo_lag"])  # env/grid.yaml, then tuning/algo/grid_ppo_lag.yaml
    assert lag.algo.cost_limit == [0.3, 0.15] and (lag.algo.lr, lag.algo.entropy_coef) == (1e-3, 0.01)
    assert (lag.eval_deterministic, lag.eval_episodes, lag.total_steps) == (False, 1000, 150000)
    for algo in ("ppo", "trpo_lag"):  # the evaluation and the budgets are the task's; the rates ppo_lag's
        other = compose_config(["env=grid", f"algo={algo}", "eval_episodes=50"])
        assert (other.eval_deterministic, other.eval_episodes, other.algo.cost_limit) == (False, 50, [0.3, 0.15])
    assert compose_config(["env=grid", "env.slip=0.2"]).env.slip == 0.2


@pytest.mark.parametrize("env", ["safe_nav", "safety_gym"])
def test_the_navigation_family_declares_its_lagrangians_preset(env):
    lag = compose_config([f"env={env}", "algo=ppo_lag"])  # the whole batch, the slower log dual, capped
    assert (lag.algo.num_minibatches, lag.algo.update_epochs, lag.algo.advantage_scale) == (1, 10, "standardized")
    assert (lag.algo.multiplier.kind, lag.algo.multiplier.lr, lag.algo.multiplier.init) == ("log", 0.5, 1.0)
    assert lag.algo.multiplier.max == 5.0
    pid = compose_config([f"env={env}", "algo=pid_lag"])  # the same batch and scale under PID's own gains
    assert (pid.algo.num_minibatches, pid.algo.update_epochs, pid.algo.advantage_scale) == (1, 10, "standardized")
    assert (pid.algo.multiplier.kind, pid.algo.multiplier.kp, pid.algo.multiplier.max) == ("pid", 2.0, 5.0)
    assert pid.algo.multiplier.ki == 0.1  # the gain its runs were measured with
    suite = compose_config(["env=suite", "algo=pid_lag"]).algo  # elsewhere: its defaults
    assert (suite.advantage_scale, suite.multiplier.ki, suite.multiplier.max) == ("standardized", 1.0, float("inf"))
    trpo = compose_config([f"env={env}", "algo=trpo_lag"])  # no preset: its defaults
    assert (trpo.algo.multiplier.kind, trpo.algo.multiplier.ki, trpo.algo.multiplier.max) == ("pid", 1.0, float("inf"))


def test_the_command_line_wins_over_tuning():
    cfg = compose_config(["env=reach1d_torch", "algo.lr=5e-4", "algo.multiplier.init=0.05", "policy.hidden_sizes=[16]"])
    assert (cfg.algo.lr, cfg.algo.multiplier.init, cfg.policy.hidden_sizes) == (5e-4, 0.05, [16])


@pytest.mark.slow  # a learning run (pyproject: markers)
def test_the_batched_preset_reaches_the_gym_runs_quality_on_its_budget(tmp_path):
    # The foundation issue's criterion: eval cost <= 1.5 and eval return within 0.05 of PPO's 0.385.
    # The preset's budget is 1M steps (32 iterations, about 5 s); 8 seeds met it (docs/throughput.md).
    cfg = compose_config(["env=reach1d_torch", "seed=0"])
    result = train(cfg, tmp_path, echo=lambda s: None)
    assert result["steps"] == 1_048_576
    assert result["episode_return"] >= 0.335, result
    assert result["episode_cost"] <= 1.5, result


def test_every_algorithm_that_picks_a_multiplier_kind_reads_the_kinds_preset_files():
    """A preset file for one multiplier kind (configs/tuning/multiplier/<env>_<algo>_<kind>.yaml) is read only where
    the algorithm's defaults list it: every algorithm that picks a kind lists it (those that override a kind inherit
    the line), so that such a file is never silently ignored."""
    include = "optional /tuning/multiplier@_global_: ${env}_${algo}_${algo/multiplier}"
    pickers = [p for p in sorted((CONFIG_DIR / "algo").glob("*.yaml")) if "\n  - multiplier:" in p.read_text()]
    assert len(pickers) >= 6, pickers  # ppo_lag, trpo_lag, cup, focops, sac_lag, td3_lag
    assert [p.name for p in pickers if include not in p.read_text()] == []
