"""Sweeps through Hydra's launchers, as a user starts them: two-job multiruns of train.py through
joblib and through submitit's local launcher (the SLURM path, run locally), a failing job that
must not cost the other its results, and the SLURM launcher's config composing."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cmdp_rl.report.sweeps import FAILED, OK, find_runs
from lab.sweeps import missing_jobs

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "env.start=0.1",
    "seed=0",
    "total_steps=256",
    "rollout_steps=32",
    "env.num_envs=4",
    "eval_episodes=4",
    "algo.update_epochs=1",
    "algo.num_minibatches=2",
]


def multirun(tmp_path, *args):
    cmd = [sys.executable, str(ROOT / "train.py"), "-m", *args, *TINY, f"hydra.sweep.dir={tmp_path}"]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)


def check_two_penalty_runs(sweep_dir):
    runs = find_runs(sweep_dir)
    assert [r.status for r in runs] == [OK, OK]
    assert sorted(r.get("algo.penalty") for r in runs) == [0.0, 5.0]
    for r in runs:
        assert r.get("env.wall") == "pass" and r.get("threads") == 1
        assert r.eval["episodes"] == 4 and r.eval["torch_threads"] == 1  # side by side: 1 thread each
        assert len(r.metrics) == 2  # 256 steps in iterations of 32 x 4
    assert missing_jobs(sweep_dir, runs) == []


@pytest.mark.parametrize("launcher", ["joblib", "submitit_local"])
def test_two_job_multirun_through_a_launcher(tmp_path, launcher):
    proc = multirun(tmp_path, "+experiment=penalty_sweep", f"hydra/launcher={launcher}", "algo.penalty=0,5")
    assert proc.returncode == 0, proc.stderr[-3000:]
    check_two_penalty_runs(tmp_path)
    if launcher == "submitit_local":
        assert (tmp_path / ".submitit").is_dir()


def test_a_failing_job_does_not_lose_the_others_results(tmp_path):
    proc = multirun(
        tmp_path,
        "+experiment=constraint_sweep",
        "hydra/launcher=joblib",
        "algo=sweep/ppo_lag",
        "algo.cost_limit=-1,0.5",
    )
    assert proc.returncode != 0  # Hydra raises once every job has finished
    assert "algo.cost_limit must be a number >= 0" in proc.stderr
    runs = {r.get("algo.cost_limit"): r for r in find_runs(tmp_path)}
    assert runs[0.5].status == OK and json.loads((runs[0.5].path / "eval.json").read_text())["episodes"] == 4
    assert runs[-1].status == FAILED and runs[-1].error.startswith("ConfigError: algo.cost_limit")
    assert not (runs[-1].path / "metrics.csv").exists()


def test_slurm_launcher_config_composes_with_the_sweeps():
    cmd = [
        sys.executable,
        str(ROOT / "train.py"),
        "+experiment=constraint_sweep",
        "hydra/launcher=submitit_slurm",
        "hydra.launcher.partition=cpu",
        "hydra.launcher.timeout_min=30",
        "hydra.launcher.cpus_per_task=1",
        "--cfg",
        "hydra",
        "--package",
        "hydra.launcher",
    ]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    launcher = yaml.safe_load(proc.stdout)  # the hydra.launcher node alone
    assert launcher["_target_"].endswith("SlurmLauncher")
    assert (launcher["partition"], launcher["timeout_min"], launcher["cpus_per_task"]) == ("cpu", 30, 1)


def test_two_job_multirun_through_ray(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_ray_launcher", reason="optional: pip install -e '.[ray]'")
    proc = multirun(
        tmp_path,
        "+experiment=penalty_sweep",
        "hydra/launcher=ray",
        "+hydra.launcher.ray.init.num_cpus=2",
        "algo.penalty=0,5",
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    check_two_penalty_runs(tmp_path)
