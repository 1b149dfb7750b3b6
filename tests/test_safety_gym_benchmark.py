"""The Safety-Gymnasium benchmark's report, from finished run directories (no training here; the
sweep itself is smoke-run by hand: see configs/experiment/safety_gym_benchmark.yaml)."""

import csv
import json
from pathlib import Path

import pytest
import yaml

from cmdp_rl.config.run_config import compose_config
from lab.bench import safety_gym_benchmark

# task, algo, seed -> final eval return, eval cost, training cost rate
RUNS = {
    ("SafetyPointGoal1-v0", "ppo", 0): (20.0, 60.0, 0.06),
    ("SafetyPointGoal1-v0", "ppo", 1): (10.0, 40.0, 0.04),
    ("SafetyPointGoal1-v0", "cpo", 0): (9.0, 20.0, 0.02),
    ("SafetyCarGoal1-v0", "ppo", 0): (30.0, 80.0, 0.08),
    ("SafetyCarGoal1-v0", "pid_lag", 0): (6.0, 30.0, 0.03),
}


def _fake_sweep(root: Path, safe_nav: bool = False) -> None:
    for (task, algo, seed), (ret, cost, rate) in RUNS.items():
        d = root / f"{task}_{algo}_s{seed}"
        d.mkdir(parents=True)
        env = (
            {"name": "safe_nav", "task": task.removeprefix("Safety").removesuffix("-v0")}
            if safe_nav
            else {"name": "safety_gym", "task": task}
        )
        (d / "config.yaml").write_text(
            yaml.safe_dump({"algo": {"name": algo}, "seed": seed, "env": {**env, "num_envs": 8}})
        )
        (d / "eval.json").write_text(
            json.dumps(
                {
                    "episode_return": ret,
                    "episode_cost": cost,
                    "cost_rate": rate,
                    "cost_limit": 25.0,
                    "steps": 8000,
                    "train_time_s": 60.0,
                }
            )
        )
        with open(d / "metrics.csv", "w", newline="") as f:
            w = csv.DictWriter(f, ["step", "episode_return", "episode_cost", "cost_rate"])
            w.writeheader()
            for i in (1, 2):
                w.writerow(
                    {"step": 4000 * i, "episode_return": ret * i / 2, "episode_cost": cost * i / 2, "cost_rate": rate}
                )


def test_report_is_per_task_with_omnisafes_numbers_beside(tmp_path):
    _fake_sweep(tmp_path)
    report = safety_gym_benchmark.gather(tmp_path, speed_episodes=0)
    point = {r["algo"]: r for r in csv.DictReader(open(tmp_path / "SafetyPointGoal1-v0" / "table.csv"))}
    car = {r["algo"]: r for r in csv.DictReader(open(tmp_path / "SafetyCarGoal1-v0" / "table.csv"))}
    assert list(point) == ["ppo", "cpo"] and list(car) == ["ppo", "pid_lag"]  # each task normalized by its own ppo
    assert float(point["ppo"]["episode_return"]) == 15.0
    assert float(point["cpo"]["normalized_return"]) == pytest.approx(9 / 15)
    assert float(car["pid_lag"]["normalized_cost_rate"]) == pytest.approx(0.03 / 0.08)
    assert (tmp_path / "SafetyCarGoal1-v0" / "curves.png").stat().st_size > 10_000
    assert report.index("## SafetyPointGoal1-v0") < report.index("## SafetyCarGoal1-v0")
    assert "| pid_lag | CPPOPID | 10.60 ± 2.51 | 30.66 ± 7.53 |" in report  # OmniSafe's CarGoal1 row
    assert "## Speed" not in report and (tmp_path / "report.md").read_text() == report


def test_a_sweep_on_safe_nav_reports_under_the_package_task_names(tmp_path):
    _fake_sweep(tmp_path, safe_nav=True)  # env.task=PointGoal1 on env=safe_nav is SafetyPointGoal1-v0
    report = safety_gym_benchmark.gather(tmp_path, speed_episodes=0)
    point = {r["algo"]: r for r in csv.DictReader(open(tmp_path / "SafetyPointGoal1-v0" / "table.csv"))}
    assert float(point["cpo"]["normalized_return"]) == pytest.approx(9 / 15)
    assert "Trained on `env=safe_nav`" in report and "| pid_lag | CPPOPID | 10.60 ± 2.51 | 30.66 ± 7.53 |" in report


def test_the_experiment_config_is_the_benchmark():
    cfg = compose_config(["+experiment=safety_gym_benchmark"])
    assert cfg.env.name == "safety_gym" and cfg.total_steps == 500_000 and cfg.algo.cost_limit == 25.0
    sweep = yaml.safe_load(
        (Path(__file__).resolve().parents[1] / "configs/experiment/safety_gym_benchmark.yaml").read_text()
    )["hydra"]["sweeper"]["params"]
    assert sweep == {
        "env.task": "SafetyPointGoal1-v0,SafetyCarGoal1-v0",
        "algo": "ppo,ppo_lag,pid_lag,cpo",
        "seed": "0,1,2",
    }
