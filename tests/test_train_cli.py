"""train.py as a user runs it, in a subprocess; the config errors through its main() in this process
(tests/helpers/cli.py: the same exit status and output, without a new interpreter's imports)."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.cli import train_py

ROOT = Path(__file__).resolve().parents[1]
SHORT = [
    "total_steps=512",
    "rollout_steps=64",
    "env.num_envs=4",
    "eval_episodes=4",
    "algo.update_epochs=2",
    "algo.num_minibatches=2",
]


def run(*args, cwd=ROOT):
    return subprocess.run(
        [sys.executable, str(ROOT / "train.py"), *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def test_each_algorithm_trains_and_writes_its_outputs(tmp_path):
    proc = run(
        "-m",
        "algo=ppo,penalty,ppo_lag,pid_lag",
        "env=reach1d",
        *SHORT,
        f"hydra.sweep.dir={tmp_path}",
        "hydra.sweep.subdir=${algo.name}",
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    for name, lam in (("ppo", 0.0), ("penalty", 1.0), ("ppo_lag", None), ("pid_lag", None)):
        out = tmp_path / name
        rows = list(csv.DictReader(open(out / "metrics.csv")))
        assert len(rows) == 2 and rows[-1]["step"] == "512"
        assert {"step", "episode_return", "episode_cost", "lagrange_multiplier", "sps"} <= rows[0].keys()
        if lam is not None:
            assert all(float(r["lagrange_multiplier"]) == lam for r in rows)
        assert "cpo_case" not in rows[0]  # each algorithm writes the statistics it declares, no others
        ev = json.loads((out / "eval.json").read_text())
        assert ev["episodes"] == 4 and {"episode_return", "episode_cost", "episode_return_std"} <= ev.keys()
        assert (out / "checkpoint.pt").is_file() and (out / ".hydra" / "config.yaml").is_file()
        assert (out / "config.yaml").is_file()
    assert "done: ppo_lag 512 steps" in proc.stdout


def test_cpo_trains_and_logs_its_dual(tmp_path):
    proc = run(
        "algo=cpo",
        "env=reach1d",
        "env.wall=pass",
        "algo.cost_limit=0.5",
        "algo.critic_epochs=2",
        *[a for a in SHORT if not a.startswith("algo.")],
        f"hydra.run.dir={tmp_path}",
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = list(csv.DictReader(open(tmp_path / "metrics.csv")))
    assert len(rows) == 2 and rows[-1]["step"] == "512"
    for r in rows:
        assert r["cpo_case"] in {"0", "1", "2"} and 0.0 <= float(r["step_fraction"]) <= 1.0
        assert float(r["kl"]) <= 0.01 and float(r["lagrange_multiplier"]) == float(r["dual_nu"]) >= 0.0
    ev = json.loads((tmp_path / "eval.json").read_text())
    assert ev["episodes"] == 4 and ev["cost_limit"] == 0.5
    assert "done: cpo 512 steps" in proc.stdout


@pytest.mark.parametrize(
    "args,message",
    [
        (["algo=no_such_algo"], "algo"),
        (["algo.cost_limit=-1"], "algo.cost_limit must be a number >= 0"),
        (["algo.gamma=1.0"], "algo.gamma must be in [0, 1)"),
        (["total_steps=0"], "total_steps must be a positive integer"),
        (["env.wall=soft"], "env.wall must be one of"),
    ],
)
def test_bad_input_fails_before_training_with_the_field_named(tmp_path, args, message):
    proc = train_py(*args, f"hydra.run.dir={tmp_path}")
    assert proc.returncode != 0
    assert message in proc.stderr + proc.stdout
    assert not (tmp_path / "metrics.csv").exists()


@pytest.mark.parametrize(
    "algo",
    [
        ["algo=ppo_lag", "algo.update_epochs=2", "algo.num_minibatches=2"],  # the PPO family
        ["algo=cpo", "algo.critic_epochs=2", "algo.critic_minibatches=2"],  # CPO (second derivatives)
    ],
    ids=["ppo_lag", "cpo"],
)
def test_each_memory_policy_trains_and_evaluates(tmp_path, algo):
    """One multirun per algorithm family: every history-dependent head on the probe env (a 2-D
    action), from train.py to eval.json and a checkpoint that reloads and replays the evaluation."""
    from cmdp_rl import evaluate, load_config, make_agent, make_env
    from cmdp_rl.run.checkpoint import load_checkpoint
    from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET

    short = ["total_steps=512", "rollout_steps=64", "env.num_envs=4", "eval_episodes=4"]
    proc = run(
        "-m",
        "policy=lstm,gru,transformer",
        "env.probe=true",
        *short,
        *algo,
        f"hydra.sweep.dir={tmp_path}",
        "hydra.sweep.subdir=${policy.name}",
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    name_of_algo = algo[0].split("=")[1]
    for name in ("lstm", "gru", "transformer"):
        out = tmp_path / name
        rows = list(csv.DictReader(open(out / "metrics.csv")))
        assert len(rows) == 2 and all(float(r["loss_v"]) > 0 for r in rows)
        ev = json.loads((out / "eval.json").read_text())
        assert ev["episodes"] == 4
        state = load_checkpoint(out / "checkpoint.pt", algo=name_of_algo, policy=name)
        cfg = load_config(state["members"][0]["config"])
        ac = make_agent(cfg.policy, make_env(cfg.env))
        ac.load_state_dict(state["members"][0]["algo_state"]["networks"])
        # the reloaded memory policy replays the run's own evaluation exactly
        again = evaluate(
            ac,
            make_env(cfg.env, num_envs=4),
            4,
            True,
            seed=cfg.seed + EVAL_SEED_OFFSET,
            termination_metric=cfg.env.termination_metric,
        )
        assert again["episode_return"] == pytest.approx(ev["episode_return"], abs=1e-6)
        assert again["episode_cost"] == ev["episode_cost"]
