"""Every range-checked field rejects a bad value with a message naming it, before training."""

import dataclasses

import pytest
import torch

from cmdp_rl import ConfigError, load_config
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.envs import GymVecEnv, Reach1D

BAD = [
    ({"algo": {"name": "no_such_algo"}}, "algo.name"),
    ({"env": {"name": "cartpole"}}, "env.name"),
    ({"env": {"backend": "jax"}}, "env.backend"),
    ({"env": {"num_envs": 0}}, "env.num_envs"),
    ({"env": {"obs_noise": -0.1}}, "env.obs_noise"),
    ({"env": {"wall_x": 1.5}}, "env.wall_x"),
    ({"env": {"goal": 2.0}}, "env.goal"),
    ({"env": {"max_steps": 0}}, "env.max_steps"),
    ({"env": {"wall": "soft"}}, "env.wall"),
    ({"env": {"start": [0.6, 0.2]}}, "env.start"),
    ({"env": {"start": 1.2}}, "env.start"),
    ({"env": {"probe": "yes"}}, "env.probe"),
    ({"policy": {"name": "cnn"}}, "policy.name"),
    ({"policy": {"hidden_sizes": [64, 0]}}, "policy.hidden_sizes"),
    ({"policy": {"activation": "gelu2"}}, "policy.activation"),
    ({"algo": {"name": "ppo_lag", "cost_limit": -1.0}}, "algo.cost_limit"),
    ({"algo": {"name": "ppo", "gamma": 1.0}}, "algo.gamma"),
    ({"algo": {"name": "ppo", "gamma": -0.1}}, "algo.gamma"),
    ({"algo": {"name": "ppo", "cost_gamma": 1.5}}, "algo.cost_gamma"),
    ({"algo": {"name": "ppo", "lr": 0.0}}, "algo.lr"),
    ({"algo": {"name": "ppo", "critic_lr": -1e-3}}, "algo.critic_lr"),
    ({"algo": {"name": "ppo", "gae_lambda": 1.1}}, "algo.gae_lambda"),
    ({"algo": {"name": "ppo", "clip_epsilon": 0.0}}, "algo.clip_epsilon"),
    ({"algo": {"name": "ppo", "update_epochs": 0}}, "algo.update_epochs"),
    ({"algo": {"name": "ppo", "num_minibatches": 0}}, "algo.num_minibatches"),
    ({"algo": {"name": "ppo", "num_minibatches": 10**9}}, "algo.num_minibatches"),
    ({"algo": {"name": "ppo", "entropy_coef": -1.0}}, "algo.entropy_coef"),
    ({"algo": {"name": "ppo", "max_grad_norm": 0.0}}, "algo.max_grad_norm"),
    ({"algo": {"name": "penalty", "penalty": -2.0}}, "algo.penalty"),
    ({"algo": {"name": "ppo_lag", "multiplier": {"init": -1.0}}}, "algo.multiplier.init"),
    ({"algo": {"name": "ppo_lag", "multiplier": {"lr": 0.0}}}, "algo.multiplier.lr"),
    ({"algo": {"name": "ppo_lag", "multiplier": {"kind": "adam"}}}, "algo.multiplier.kind"),
    ({"algo": {"name": "ppo_lag", "multiplier": {"kind": "dual", "scale": "cost"}}}, "algo.multiplier.scale"),
    (
        {"algo": {"name": "ppo_lag", "multiplier": {"kind": "regularized", "lr": 0.5, "tau": 2.0}}},
        "algo.multiplier.tau",
    ),
    ({"algo": {"name": "ppo_lag", "multiplier": {"kind": "optimistic", "nu": 1.0}}}, "algo.multiplier.nu"),
    ({"algo": {"name": "ppo_lag", "multiplier": {"kind": "dual", "nu": 0.5}}}, "algo.multiplier"),  # not dual's
    ({"algo": {"name": "ppo_lag", "multiplier": {"rho": 1.0}}}, "algo.multiplier"),  # no such field
    ({"algo": {"name": "ppo_lag", "multiplier": "dual"}}, "algo.multiplier"),  # the node, not a kind's name
    ({"algo": {"name": "ppo_lag", "lambda_lr": 0.1}}, "algo"),  # the flat name of before the node
    ({"algo": {"name": "ppo", "multiplier": {"lr": 0.1}}}, "algo"),  # an unconstrained algorithm has none
    ({"algo": {"name": "ppo", "penalty": 1.0}}, "algo"),  # option of another algorithm
    ({"algo": {"name": "pid_lag", "multiplier": {"kp": -0.1}}}, "algo.multiplier.kp"),
    ({"algo": {"name": "pid_lag", "multiplier": {"ki": -0.1}}}, "algo.multiplier.ki"),
    ({"algo": {"name": "pid_lag", "multiplier": {"kd": float("nan")}}}, "algo.multiplier.kd"),
    (
        {"algo": {"name": "pid_lag", "multiplier": {"kp": 0.0, "ki": 0.0, "kd": 0.0}}},
        "algo.multiplier.kp + algo.multiplier.ki + algo.multiplier.kd",
    ),
    ({"algo": {"name": "pid_lag", "multiplier": {"p_ema_alpha": 1.0}}}, "algo.multiplier.p_ema_alpha"),
    ({"algo": {"name": "pid_lag", "multiplier": {"d_ema_alpha": -0.5}}}, "algo.multiplier.d_ema_alpha"),
    ({"algo": {"name": "pid_lag", "multiplier": {"d_delay": 0}}}, "algo.multiplier.d_delay"),
    ({"algo": {"name": "pid_lag", "multiplier": {"max": 0.0}}}, "algo.multiplier.max"),
    ({"algo": {"name": "pid_lag", "multiplier": {"init": 5.0, "max": 2.0}}}, "algo.multiplier.init"),
    ({"algo": {"name": "sac_lag", "multiplier": {"kind": "pid", "kp": 0.0, "ki": 0.0}}}, "algo.multiplier.kp"),
    ({"algo": {"name": "cpo", "target_kl": 0.0}}, "algo.target_kl"),
    ({"algo": {"name": "cpo", "cg_iters": 0}}, "algo.cg_iters"),
    ({"algo": {"name": "cpo", "cg_damping": -0.1}}, "algo.cg_damping"),
    ({"algo": {"name": "cpo", "line_search_steps": 0}}, "algo.line_search_steps"),
    ({"algo": {"name": "cpo", "backtrack_coef": 1.0}}, "algo.backtrack_coef"),
    ({"algo": {"name": "cpo", "critic_epochs": 0}}, "algo.critic_epochs"),
    ({"algo": {"name": "cpo", "critic_minibatches": 10**9}}, "algo.critic_minibatches"),
    ({"algo": {"name": "cpo", "critic_lr": 0.0}}, "algo.critic_lr"),
    ({"algo": {"name": "cpo", "cost_limit": -1.0}}, "algo.cost_limit"),
    ({"algo": {"name": "cpo", "clip_epsilon": 0.2}}, "algo"),  # a PPO option: CPO has no clip
    ({"algo": {"name": "ppo", "lr": "fast"}}, "algo.lr"),
    ({"total_steps": 0}, "total_steps"),
    ({"total_steps": -5}, "total_steps"),
    ({"rollout_steps": 0}, "rollout_steps"),
    ({"device": "tpu"}, "device"),
    ({"threads": 0}, "threads"),
    ({"eval_episodes": 0}, "eval_episodes"),
    ({"checkpoint_every": 0}, "checkpoint_every"),
    ({"log_interval": 0}, "log_interval"),
    ({"bogus": 1}, "config"),
    ({"resume": 5}, "resume must be null or a run directory"),
    ({"resume": ""}, "resume"),
    ({"logger": {"name": "mlflow"}}, "logger.name"),
    ({"logger": {"flush_secs": 5}}, "logger"),
]


@pytest.mark.parametrize("override,field", BAD, ids=[f for _, f in BAD])
def test_bad_value_names_the_field(override, field):
    with pytest.raises(ConfigError) as err:
        load_config(override)
    assert str(err.value).startswith(field), str(err.value)


def test_defaults_and_coercion():
    cfg = load_config({"algo": {"name": "penalty", "penalty": 3}, "total_steps": 1000.0})
    assert cfg.algo.penalty == 3.0 and isinstance(cfg.algo.penalty, float) and cfg.total_steps == 1000
    assert load_config({}).algo.name == "ppo_lag"


def test_wrong_shaped_action_is_rejected():
    env = GymVecEnv(lambda: Reach1D(), 2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action: expected shape \(2, 1\)"):
        env.step(torch.zeros(2, 2))
    with pytest.raises(ValueError, match="action"):
        env.step(torch.zeros(1))


@pytest.mark.parametrize(
    "num_envs,rollout,epochs,minibatches",
    [
        (1, 256, 10, 8),
        (8, 256, 10, 8),  # the gym default, unchanged
        (16, 128, 10, 8),
        (64, 32, 10, 8),  # batch 2048
        (256, 32, 5, 16),  # batch 8192: minibatches of 512, ~80 steps
        (1024, 32, 1, 64),
        (16384, 32, 1, 64),  # one pass; 64 minibatches of 512, then larger
    ],
)
def test_auto_batch_shape_follows_num_envs(num_envs, rollout, epochs, minibatches):
    cfg = load_config({"env": {"num_envs": num_envs, "backend": "torch"}})
    assert (cfg.rollout_steps, cfg.algo.update_epochs, cfg.algo.num_minibatches) == (rollout, epochs, minibatches)


def test_auto_keeps_given_numbers_and_rejects_other_words():
    cfg = load_config({"env": {"num_envs": 1024}, "rollout_steps": 64, "algo": {"num_minibatches": 4}})
    assert (cfg.rollout_steps, cfg.algo.num_minibatches, cfg.algo.update_epochs) == (64, 4, 20)
    cfg = load_config({"algo": {"name": "cpo"}, "env": {"num_envs": 1024}})  # CPO: only the rollout is auto
    assert cfg.rollout_steps == 32 and not hasattr(cfg.algo, "update_epochs")
    for raw, field in (
        ({"rollout_steps": "many"}, "rollout_steps"),
        ({"algo": {"update_epochs": "lots"}}, "algo.update_epochs"),
        ({"algo": {"num_minibatches": "some"}}, "algo.num_minibatches"),
    ):
        with pytest.raises(ConfigError, match=f"^{field} must be a positive integer or 'auto'"):
            load_config(raw)


@pytest.mark.parametrize(
    "overrides, fields",
    [
        (["algo=ppo_lag"], {"kind", "lr", "init", "max", "saturation"}),
        (["algo=ppo_lag", "algo/multiplier=dual"], {"kind", "lr", "init", "scale", "max"}),
        (["algo=pid_lag"], {"kind", "kp", "ki", "kd", "p_ema_alpha", "d_ema_alpha", "d_delay", "init", "scale", "max"}),
        (["algo=trpo_lag", "algo/multiplier=regularized"], {"kind", "lr", "tau", "init", "scale", "max"}),
    ],
)
def test_the_multiplier_node_holds_only_its_kinds_options(overrides, fields):
    cfg = compose_config(overrides)
    assert {f.name for f in dataclasses.fields(cfg.algo.multiplier)} == fields


def _leaves(node) -> list[str]:
    out = []
    for f in dataclasses.fields(node):
        value = getattr(node, f.name)
        out += [f"{f.name}.{x}" for x in _leaves(value)] if dataclasses.is_dataclass(value) else [f.name]
    return out


def test_ppo_lag_shows_at_most_20_options():
    """What --cfg job lists under algo (issue 52): the options that act, the chosen multiplier kind's only (pid_lag
    shows PID's gains instead of the step: test_the_multiplier_node_holds_only_its_kinds_options)."""
    options = [x for x in _leaves(compose_config(["algo=ppo_lag"]).algo) if x != "name"]
    assert len(options) <= 20, options
