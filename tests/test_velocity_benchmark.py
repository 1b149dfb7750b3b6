"""The velocity benchmark's report: table and curves from finished run directories."""

import csv
import json
from pathlib import Path

import pytest
import yaml
from helpers.runs import run_script

from lab.bench import velocity_benchmark

# algo, seed -> final eval return, eval cost, training cost rate
RUNS = {
    ("ppo", 0): (3000.0, 500.0, 0.4),
    ("ppo", 1): (1000.0, 300.0, 0.2),
    ("ppo_lag", 0): (1500.0, 20.0, 0.05),
    ("ppo_lag", 1): (500.0, 45.0, 0.15),
}


def _fake_sweep(root: Path) -> None:
    for (algo, seed), (ret, cost, rate) in RUNS.items():
        d = root / f"{algo}_s{seed}"
        d.mkdir(parents=True)
        (d / "config.yaml").write_text(
            yaml.safe_dump({"algo": {"name": algo}, "seed": seed, "env": {"name": "velocity", "task": "HalfCheetah"}})
        )
        (d / "eval.json").write_text(
            json.dumps(
                {
                    "episode_return": ret,
                    "episode_cost": cost,
                    "cost_rate": rate,
                    "cost_limit": 25.0,
                    "steps": 4096,
                    "train_time_s": 60.0,
                }
            )
        )
        with open(d / "metrics.csv", "w", newline="") as f:
            w = csv.DictWriter(f, ["step", "episode_return", "episode_cost", "cost_rate"])
            w.writeheader()
            for i in (1, 2):
                w.writerow(
                    {"step": 2048 * i, "episode_return": ret * i / 2, "episode_cost": cost * i / 2, "cost_rate": rate}
                )


def test_report_normalizes_by_the_sweeps_own_ppo_runs(tmp_path):
    _fake_sweep(tmp_path)
    velocity_benchmark.gather(tmp_path)
    rows = {r["algo"]: r for r in csv.DictReader(open(tmp_path / "table.csv"))}
    assert list(rows) == ["ppo", "ppo_lag"]
    # reference: ppo means J_r = 2000, J_c = 400, rho = 0.3
    lag = rows["ppo_lag"]
    assert float(lag["episode_return"]) == 1000.0 and float(lag["episode_cost"]) == 32.5
    assert float(lag["normalized_return"]) == pytest.approx((1500 / 2000 + 500 / 2000) / 2)
    assert float(lag["normalized_violation"]) == pytest.approx((0.0 + 20 / 375) / 2)  # seed 0 is within budget
    assert float(lag["normalized_cost_rate"]) == pytest.approx((0.05 / 0.3 + 0.15 / 0.3) / 2)
    assert float(rows["ppo"]["normalized_return"]) == pytest.approx(1.0)
    assert "| ppo_lag | 2 | 4,096 | 1000.0 ± 500.0 | 32.5 ± 12.5 |" in (tmp_path / "table.md").read_text()
    assert (tmp_path / "curves.png").stat().st_size > 10_000


def test_run_launches_the_experiment_through_train_py_and_reports(tmp_path):
    """`--run` is `train.py -m +experiment=velocity_benchmark` (train.py's resolvers and all), then
    the report, here for one tiny job of each algorithm. Its joblib launcher with one job runs them one after
    another in train.py's process: two would start two more interpreters (seconds of imports each), and
    launching side by side is tests/test_sweep_launchers.py's subject."""
    pytest.importorskip("mujoco")
    sweep = tmp_path / "sweep"
    proc = run_script(
        "experiments/benchmarks/velocity_benchmark.py",
        "--run",
        "seed=0",
        "total_steps=256",
        "rollout_steps=64",
        "env.num_envs=2",
        "env.max_steps=64",
        "eval_episodes=1",
        "hydra.launcher.n_jobs=1",
        f"hydra.sweep.dir={sweep}",
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = {r["algo"]: r for r in csv.DictReader(open(sweep / "table.csv"))}
    assert set(rows) == {"ppo", "ppo_lag", "cpo"} and all(r["steps"] == "256" for r in rows.values())
    assert (sweep / "curves.png").is_file() and (sweep / "cpo_s0" / "eval.json").is_file()
