"""Resume after a crash: nothing lost, nothing duplicated, the same final numbers."""

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from helpers.cli import train_py
from helpers.resume import assert_same_run, crash_then_resume, final_state
from helpers.runs import ROOT, cli_args, metrics_rows, run_script, tiny

from cmdp_rl import load_config, train
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.run.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from cmdp_rl.run.resume import resume_config


def test_a_pid_controller_with_every_term_resumes_exactly(tmp_path, monkeypatch, quiet):
    """Every algorithm resumes exactly with its default options (tests/test_registry_enrolment.py); pid_lag's
    defaults leave the derivative and both filters off, so here every term of the controller carries state
    (the integral, the two EMAs, the delayed costs) across the resume."""
    cfg = tiny(algo={"name": "pid_lag"})
    cfg["algo"]["multiplier"] = {
        "kind": "pid",
        "kp": 1.0,
        "ki": 0.5,
        "kd": 0.5,
        "p_ema_alpha": 0.5,
        "d_ema_alpha": 0.5,
        "d_delay": 2,
    }

    def crashed_past_the_last_checkpoint(broken: Path) -> None:  # checkpoints at 2 and 4, then row 5
        assert len(metrics_rows(broken)) == 5 and load_checkpoint(broken / "checkpoint.pt")["iteration"] == 4

    assert_same_run(*crash_then_resume(cfg, tmp_path, monkeypatch, quiet, checked=crashed_past_the_last_checkpoint))


def test_resume_can_extend_a_finished_run(tmp_path, quiet):
    long, short = tmp_path / "long", tmp_path / "short"
    train(load_config(tiny()), long, echo=quiet)
    train(load_config(tiny(total_steps=4 * 32)), short, echo=quiet)
    train(load_config(tiny(resume=str(short))), echo=quiet)  # total_steps of the long run
    assert_same_run(long, short)


def test_sigkill_at_a_random_point_then_resume_loses_nothing(tmp_path, quiet):
    # 40 iterations with the kill in the first 11 (+ <= 0.2 s): far from the end even on a fast machine,
    # where 14 iterations once ended within 0.1 s of the kill point.
    iterations = 40
    cfg = tiny(total_steps=iterations * 32)
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    train(load_config(cfg), whole, echo=quiet)

    rng = random.Random()
    rows_before_kill, extra_sleep = rng.randint(1, 11), rng.uniform(0.0, 0.2)
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "train.py"), *cli_args(cfg), f"hydra.run.dir={killed}"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        if (killed / "checkpoint.pt").exists() and (killed / "metrics.csv").exists():
            if (killed / "metrics.csv").read_text().count("\n") - 1 >= rows_before_kill:
                break
        time.sleep(0.005)
    time.sleep(extra_sleep)
    assert proc.poll() is None, "the run finished before the kill: make it longer"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    where = f"killed after row {rows_before_kill} + {extra_sleep:.3f}s"
    assert len(metrics_rows(killed)) < iterations, where

    res = run_script("train.py", f"resume={killed}")
    assert res.returncode == 0, f"{where}\n{res.stderr[-3000:]}"
    assert "resuming" in res.stdout
    assert_same_run(whole, killed)
    # Hydra's record of the first command stays; the resume's goes beside it
    assert (killed / ".hydra" / "overrides.yaml").is_file()
    assert list((killed / ".hydra").glob("resume_*/overrides.yaml"))


def test_a_kill_while_writing_a_checkpoint_leaves_the_previous_one(tmp_path):
    """save_checkpoint is atomic: SIGKILL a process that rewrites a large checkpoint in a loop."""
    path = tmp_path / "ckpt.pt"
    code = (
        "import sys, torch; from cmdp_rl.run.checkpoint import save_checkpoint\n"
        "i = 0\n"
        "while True:\n"
        "    save_checkpoint(sys.argv[1], {'i': i, 'w': torch.full((4_000_000,), float(i))})\n"
        "    print(i, flush=True); i += 1\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code, str(path)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    first = proc.stdout.readline()  # one checkpoint is complete
    assert first.strip() == "0"
    time.sleep(random.uniform(0.0, 0.3))  # somewhere inside a later write
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    state = load_checkpoint(path)
    assert torch.equal(state["w"], torch.full((4_000_000,), float(state["i"])))


def test_failed_write_keeps_the_old_checkpoint(tmp_path, monkeypatch):
    path = tmp_path / "c.pt"
    save_checkpoint(path, {"i": 1})

    def broken_save(obj, f):
        f.write(b"half a checkpoint")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError):
        save_checkpoint(path, {"i": 2})
    monkeypatch.undo()
    assert load_checkpoint(path)["i"] == 1


def test_resume_refuses_another_algorithm_policy_or_config(tmp_path, quiet):
    run = tmp_path / "run"
    train(load_config(tiny(total_steps=64)), run, echo=quiet)
    with pytest.raises(CheckpointError, match="run of algo='ppo_lag', but this command asks for algo='ppo'"):
        resume_config(run, {**tiny(), "algo": {"name": "ppo"}}, ["algo"])
    with pytest.raises(ConfigError, match=r"^env.num_envs cannot change when resuming"):
        resume_config(run, tiny(env={"num_envs": 4}), ["env.num_envs"])
    with pytest.raises(ConfigError, match=r"^algo.cost_limit cannot change"):
        resume_config(run, tiny(algo={"cost_limit": 3.0}), ["algo.cost_limit"])
    # the library path checks too: a config that differs from the run's is refused
    with pytest.raises(ConfigError, match="rollout_steps"):
        train(load_config(tiny(rollout_steps=8, resume=str(run))), echo=quiet)
    ok = resume_config(run, tiny(total_steps=96, log_interval=3), ["total_steps", "log_interval", "algo"])
    assert ok.total_steps == 96 and ok.log_interval == 3 and ok.algo.cost_limit == 0.2


def test_resume_refuses_lost_rows_a_lost_metrics_file_and_a_missing_checkpoint(tmp_path, quiet):
    run = tmp_path / "run"
    train(load_config(tiny(total_steps=4 * 32)), run, echo=quiet)
    lines = (run / "metrics.csv").read_text().splitlines(keepends=True)
    (run / "metrics.csv").write_text("".join(lines[:3]))  # header + rows 1, 2; checkpoint at 4
    with pytest.raises(CheckpointError, match="does not hold rows 1..4"):
        train(load_config(tiny(resume=str(run))), echo=quiet)
    (run / "metrics.csv").unlink()
    with pytest.raises(CheckpointError, match="metrics.csv is missing"):
        train(load_config(tiny(resume=str(run))), echo=quiet)
    (run / "checkpoint.pt").unlink()  # killed before its first checkpoint
    with pytest.raises(CheckpointError, match="resume: no checkpoint.pt in"):
        train(load_config(tiny(resume=str(run))), echo=quiet)


def test_resume_cli_refuses_missing_corrupt_and_foreign_checkpoints(tmp_path, quiet):
    run = tmp_path / "run"
    train(load_config(tiny(total_steps=64)), run, echo=quiet)
    good = (run / "checkpoint.pt").read_bytes()

    def refused(message, *args):  # train.py's main() in this process: what it says is checked, not its start-up
        res = train_py(*args, f"hydra.run.dir={tmp_path / 'hydra'}")
        assert res.returncode == 2 and message in res.stderr, res.stderr[-2000:]

    refused("no run directory at", f"resume={tmp_path / 'nowhere'}")
    refused("run of algo='ppo_lag', but this command asks for algo='ppo'", f"resume={run}", "algo=ppo")
    state = load_checkpoint(run / "checkpoint.pt")
    state.pop("format")
    save_checkpoint(run / "checkpoint.pt", {**state, "policy": "lstm"})  # e.g. copied from another run
    refused("written by policy='lstm', but this run uses policy='mlp'", f"resume={run}")
    (run / "checkpoint.pt").write_bytes(good[: len(good) // 2])  # cut short
    refused("is corrupt or not a cmdp_rl checkpoint", f"resume={run}")
    assert len(metrics_rows(run)) == 2  # none of these touched the run's rows


def test_an_env_that_cannot_save_its_state_trains_but_refuses_to_resume(tmp_path, monkeypatch, quiet):
    from cmdp_rl.envs import GymVecEnv, VecEnv

    monkeypatch.setattr(GymVecEnv, "state_dict", VecEnv.state_dict)  # the interface's default
    lines = []
    train(load_config(tiny(total_steps=64)), tmp_path, echo=lines.append)
    assert any(line.startswith("warning: GymVecEnv cannot save its state") for line in lines)
    assert load_checkpoint(tmp_path / "checkpoint.pt")["members"][0]["algo_state"]  # still a usable checkpoint
    with pytest.raises(CheckpointError, match="holds no env state .* cannot continue exactly"):
        train(load_config(tiny(resume=str(tmp_path))), echo=quiet)


def test_mujoco_run_with_normalization_resumes_exactly(tmp_path, monkeypatch, quiet):
    """A MuJoCo env (its whole MjData saved) and running normalization statistics come back too."""
    pytest.importorskip("mujoco")
    cfg = {
        "env": {"name": "velocity", "task": "Hopper", "num_envs": 2, "max_steps": 24},
        "algo": {"name": "ppo_lag", "update_epochs": 1, "num_minibatches": 2, "cost_limit": 1.0},
        "normalize": {"obs": True, "reward": True, "cost": True},
        "rollout_steps": 16,
        "total_steps": 6 * 32,
        "checkpoint_every": 2,
        "eval_episodes": 2,
    }
    whole, broken = crash_then_resume(cfg, tmp_path, monkeypatch, quiet)
    assert_same_run(whole, broken)
    stats = final_state(broken)["networks"]
    assert any(k.startswith("normalizers.") for k in stats)  # the statistics were in the checkpoint


@pytest.mark.parametrize("policy", ["lstm", "transformer"])
def test_memory_policy_resumes_exactly(tmp_path, monkeypatch, quiet, policy):
    """The carried recurrent state / window and the previous action and cost are part of the
    collector's saved root: a resumed memory-policy run equals an uninterrupted one."""
    cfg = tiny(policy={"name": policy}, env={"probe": True})
    whole, broken = crash_then_resume(cfg, tmp_path, monkeypatch, quiet)
    assert_same_run(whole, broken)
