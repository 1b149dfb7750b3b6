"""The env contract as a run meets it: train() checks a separate small env before training and
every rollout after, and stops with one line naming the env, index, step and field, before any
result is written; train.py exits 2 without a traceback. A run directory that cannot be written
stops the same way."""

import pytest
import torch
from helpers import cost_envs
from helpers.cli import train_py
from helpers.runs import metrics_rows, tiny
from tensordict import TensorDict

from cmdp_rl import keys, load_config, train
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.envs import EnvContractError
from cmdp_rl.envs.contract import check_rollout
from cmdp_rl.run.rundir import RunDirError


def broken(fault: str, at: int = 1, total_steps: int = 640, **env) -> dict:
    return {
        "env": {"name": "gym", "id": cost_envs.BROKEN_ID, "num_envs": 2, "kwargs": {"fault": fault, "at": at}, **env},
        "algo": {"name": "ppo_lag", "update_epochs": 1, "num_minibatches": 2},
        "rollout_steps": 32,
        "total_steps": total_steps,
        "eval_episodes": 2,
        "log_interval": 1,
    }


@pytest.mark.parametrize(
    "fault,message",
    [
        ("nan_reward", "env cost_test/Broken-v0 (env 0, step 1): reward is nan; rewards must be finite"),
        ("inf_obs", "env cost_test/Broken-v0 (env 0, step 1): observation is not finite: [inf inf]"),
        ("nan_cost", 'env cost_test/Broken-v0 (env 0, step 1): info["cost"] is nan; costs must be finite'),
        (
            "negative_cost",
            'env cost_test/Broken-v0 (env 0, step 1): info["cost"] is -0.5; costs must be >= 0 in a CMDP',
        ),
    ],
)
def test_a_broken_env_stops_train_before_anything_is_written(tmp_path, quiet, fault, message):
    with pytest.raises(EnvContractError) as err:
        train(load_config(broken(fault)), tmp_path, echo=quiet)
    assert isinstance(err.value, ConfigError)
    text = str(err.value)
    assert text.startswith(message) and "\n" not in text
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no metrics.csv, config.yaml, run_info.json


def test_allow_negative_cost_accepts_signed_costs(tmp_path, quiet):
    res = train(load_config(broken("negative_cost", total_steps=128, allow_negative_cost=True)), tmp_path, echo=quiet)
    assert res["episode_cost"] < 0  # -0.5 a step, logged as it is


def test_allow_negative_cost_is_a_declared_env_option():
    assert load_config({}).env.allow_negative_cost is False
    with pytest.raises(ConfigError, match="env.allow_negative_cost must be true or false, got 'yes'"):
        load_config({"env": {"allow_negative_cost": "yes"}})


def test_a_fault_after_the_check_stops_the_run_at_its_rollout(tmp_path, quiet):
    """The pre-training check steps each env 100 times; a NaN reward from the 300th step on is
    caught by the per-rollout check of iteration 10 (steps 289..320), named at its env step."""
    with pytest.raises(EnvContractError) as err:
        train(load_config(broken("nan_reward", at=300)), tmp_path, echo=quiet)
    assert str(err.value).startswith("env cost_test/Broken-v0 (env 0, step 300): reward is nan")
    rows = metrics_rows(tmp_path)
    assert [int(r["iteration"]) for r in rows] == list(range(1, 10))  # the iterations before it, no more
    assert not (tmp_path / "eval.json").exists()


def _batch(n: int = 3, t: int = 5) -> TensorDict:
    return TensorDict(
        {
            keys.OBS: torch.zeros(n, t, 2),
            keys.NEXT: TensorDict(
                {keys.OBS: torch.zeros(n, t, 2), keys.REWARD: torch.zeros(n, t, 1), keys.COST: torch.zeros(n, t, 1)},
                batch_size=[n, t],
            ),
        },
        batch_size=[n, t],
    )


def test_check_rollout_names_the_earliest_breach():
    batch = _batch()
    check_rollout(batch, "x")  # all finite, costs >= 0
    batch.get(keys.NEXT).get(keys.COST)[1, 4] = -1.0
    batch.get(keys.NEXT).get(keys.COST)[2, 3] = float("nan")
    batch.get(keys.NEXT).get(keys.REWARD)[2, 4] = float("inf")
    with pytest.raises(EnvContractError, match=r'^env x \(env 2, step 13\): info\["cost"\] is nan'):
        check_rollout(batch, "x", first_step=10)  # t = 3 is the env's step 10 + 3
    batch.get(keys.NEXT).get(keys.COST)[2, 3] = 0.0
    with pytest.raises(EnvContractError, match=r'^env x \(env 1, step 14\): info\["cost"\] is -1.0'):
        check_rollout(batch, "x", first_step=10)  # env 1 before env 2 at the same step
    with pytest.raises(EnvContractError, match=r"^env x \(env 2, step 14\): reward is inf"):
        check_rollout(batch, "x", allow_negative_cost=True, first_step=10)


def test_check_rollout_dates_a_root_observation_to_the_step_that_returned_it():
    batch = _batch()
    batch.get(keys.OBS)[0, 2, 1] = float("nan")
    with pytest.raises(EnvContractError, match=r"^env x \(env 0, step 2\): observation is not finite"):
        check_rollout(batch, "x", first_step=1)
    batch = _batch()
    batch.get(keys.OBS)[1, 0, 0] = float("-inf")
    with pytest.raises(EnvContractError, match=r"^env x \(env 1, reset\): observation is not finite"):
        check_rollout(batch, "x", first_step=1)


def test_check_rollout_passes_finite_values_whose_sum_overflows():
    batch = _batch()
    batch.get(keys.NEXT).get(keys.REWARD)[:] = 3e38  # finite, but their float32 sum is inf
    check_rollout(batch, "x")


def test_the_check_leaves_the_training_numbers_alone(tmp_path, quiet, monkeypatch):
    """Same config and seed, with and without the pre-training check: the same metrics.csv."""
    import cmdp_rl.run.start as start

    cfg = tiny()
    train(load_config(cfg), tmp_path / "with", echo=quiet)
    monkeypatch.setattr(start, "check_env_contract", lambda cfg: None)
    train(load_config(cfg), tmp_path / "without", echo=quiet)
    assert metrics_rows(tmp_path / "with") == metrics_rows(tmp_path / "without")


def test_an_unwritable_run_directory_stops_train(tmp_path, quiet):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(RunDirError, match=rf"^run directory {blocker}/run cannot be created or written: "):
        train(load_config(tiny()), blocker / "run", echo=quiet)


def test_train_py_exits_2_with_one_line_on_a_broken_env(tmp_path):
    out = train_py(
        "env=gym",
        f"env.id=helpers.cost_envs:{cost_envs.BROKEN_ID}",
        "+env.kwargs.fault=negative_cost",
        f"hydra.run.dir={tmp_path}",
    )
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert lines == [
        f'config error: env helpers.cost_envs:{cost_envs.BROKEN_ID} (env 0, step 1): info["cost"] is -0.5; '
        "costs must be >= 0 in a CMDP (env.allow_negative_cost=true accepts signed costs)"
    ]
    assert not (tmp_path / "metrics.csv").exists() and not (tmp_path / "eval.json").exists()


def test_train_py_exits_2_with_one_line_on_an_unwritable_run_directory():
    out = train_py("hydra.run.dir=/proc/cmdp_rl_cannot_exist", "total_steps=64")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "cannot write outputs: run directory /proc/cmdp_rl_cannot_exist cannot be created or written: "
        "No such file or directory"
    ]
