"""The penalty-versus-constraint study's report (lab.studies.penalty_vs_constraint, the code of
experiments/studies/penalty_vs_constraint.py) on a fixture of run directories built here: finished,
failed, interrupted and never-started runs, as a sweep leaves them."""

import csv
import dataclasses
import json
from pathlib import Path

import pytest
import yaml

from cmdp_rl.algos.ppo_lag import PenaltyConfig, PPOLagConfig
from cmdp_rl.config.run_config import RunConfig
from lab.studies import penalty_vs_constraint as pvc

ROOT = Path(__file__).resolve().parents[1]

PENALTY_PARAMS = {"algo": "sweep/penalty", "algo.penalty": "0.0,2.0", "env.start": "0.1", "seed": "0,1,2"}
CONSTRAINT_PARAMS = {"algo": "sweep/ppo_lag", "algo.cost_limit": "0.5", "env.start": "[0.0,1.0]", "seed": "0,1"}


def write_sweep(d: Path, params: dict) -> None:
    d.mkdir(parents=True)
    multirun = {"hydra": {"sweeper": {"params": params}, "overrides": {"task": ["+experiment=x"]}}}
    (d / "multirun.yaml").write_text(yaml.safe_dump(multirun))


def write_run(d: Path, overrides: list, algo, start, seed, eval_=None, costs=None, error=None) -> None:
    cfg = RunConfig(algo=algo, seed=seed)
    cfg.env.wall, cfg.env.start = "pass", start
    (d / ".hydra").mkdir(parents=True)
    (d / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides + ["+experiment=x"]))
    (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(dataclasses.asdict(cfg)))
    if costs is not None:
        (d / "config.yaml").write_text(yaml.safe_dump(dataclasses.asdict(cfg)))
        with open(d / "metrics.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["iteration", "episode_return", "episode_cost", "lagrange_multiplier"])
            for i, c in enumerate(costs):
                w.writerow([i + 1, 0.5, c, 0.7 + i])
    if eval_ is not None:
        (d / "eval.json").write_text(
            json.dumps({"episode_return": eval_[0], "episode_cost": eval_[1], "episodes": 100})
        )
    if error is not None:
        (d / "error.txt").write_text(error + "\n\nTraceback ...")


@pytest.fixture
def sweep(tmp_path):
    pen, con = tmp_path / "penalty", tmp_path / "constraint"
    write_sweep(pen, PENALTY_PARAMS)
    write_sweep(con, CONSTRAINT_PARAMS)

    def pen_run(n, lam, seed, **kw):
        ovr = ["algo=sweep/penalty", f"algo.penalty={lam}", "env.start=0.1", f"seed={seed}"]
        write_run(pen / f"{n}_run", ovr, PenaltyConfig(penalty=lam), 0.1, seed, **kw)

    pen_run(0, 0.0, 0, eval_=(1.8, 1.0), costs=[3, 2, 1, 1.0])
    resumed = pen / "0_run" / ".hydra" / "resume_2026-01-01_00-00-00"  # a resume's record: not a run
    resumed.mkdir()
    for name in ("config.yaml", "overrides.yaml"):
        (resumed / name).write_text((pen / "0_run" / ".hydra" / name).read_text())
    pen_run(1, 0.0, 1, eval_=(1.6, 1.0), costs=[3, 2, 1, 0.5])
    pen_run(2, 0.0, 2, costs=[3, 2])  # interrupted: metrics, no result, no error ...
    ovr = ["algo=sweep/penalty", "algo.penalty=0.0", "env.start=0.1", "seed=2"]  # ... then run again
    write_run(pen / "rerun" / "0_run", ovr, PenaltyConfig(penalty=0.0), 0.1, 2, eval_=(1.7, 1.0), costs=[3, 2, 1, 0.75])
    pen_run(3, 2.0, 0, eval_=(0.4, 0.0), costs=[1, 0, 0, 0])
    pen_run(4, 2.0, 1, error="TrainingDiverged: loss_pi is nan", costs=[1])
    pen_run(5, 2.0, 2, eval_=(0.2, 0.0), costs=[1, 0, 0, 0])
    ovr = ["algo=sweep/ppo_lag", "algo.cost_limit=0.5", "env.start=[0.0,1.0]", "seed=0"]
    write_run(con / "0_run", ovr, PPOLagConfig(cost_limit=0.5), [0.0, 1.0], 0, eval_=(1.2, 0.4), costs=[2, 1, 0.5, 0.3])
    # seed=1 of the constraint sweep never started: no directory at all
    return tmp_path


def test_table_status_and_answers_from_a_fixture_sweep(sweep, capsys):
    out = sweep / "report"
    assert pvc.main([str(sweep), "--out", str(out)]) == 0
    rows = {(r["knob"], float(r["value"]), r["start"]): r for r in csv.DictReader(open(out / "table.csv"))}
    assert set(rows) == {("lambda", 0.0, "x0=0.1"), ("lambda", 2.0, "x0=0.1"), ("d", 0.5, "x0~U[0,1]")}

    lam0 = rows[("lambda", 0.0, "x0=0.1")]  # seed 2's rerun replaces its interrupted run
    assert (lam0["runs_ok"], lam0["runs"]) == ("3", "3")
    assert float(lam0["return_mean"]) == pytest.approx(1.7)
    assert float(lam0["return_std"]) == pytest.approx(0.1)  # over seeds, ddof=1
    assert float(lam0["cost_mean"]) == 1.0 and float(lam0["cost_std"]) == 0.0
    assert float(lam0["train_cost_mean"]) == pytest.approx(0.75)  # last quarters: 1.0, 0.5, 0.75
    assert float(lam0["train_cost_std"]) == pytest.approx(0.25)
    assert float(lam0["final_lambda_mean"]) == pytest.approx(3.7)
    assert float(lam0["predicted_cost"]) == 1.0 and lam0["check"] == "agrees"

    lam2 = rows[("lambda", 2.0, "x0=0.1")]
    assert (lam2["runs_ok"], lam2["runs"]) == ("2", "3")
    assert float(lam2["return_mean"]) == pytest.approx(0.3)
    assert float(lam2["predicted_cost"]) == 0.0 and lam2["check"] == "agrees"

    d05 = rows[("d", 0.5, "x0~U[0,1]")]
    assert (d05["algo"], d05["runs_ok"], d05["runs"]) == ("ppo_lag", "1", "2")
    assert float(d05["cost_mean"]) == pytest.approx(0.4) and d05["cost_std"] == "nan"
    assert float(d05["predicted_cost"]) == pytest.approx(0.5) and d05["check"] == "meets d"

    status = [r["status"] for r in csv.DictReader(open(out / "runs.csv"))]
    assert sorted(status) == ["failed", "missing"] + ["ok"] * 6 + ["superseded"]
    printed = capsys.readouterr().out
    assert "6 ok, 1 failed, 0 incomplete, 1 missing (1 superseded by reruns)" in printed
    assert "TrainingDiverged: loss_pi is nan" in printed
    assert "algo.cost_limit=0.5 env.start=[0.0,1.0] seed=1" in printed
    rerun = (out / "rerun.sh").read_text().splitlines()[2:]
    assert sorted(rerun) == sorted(
        [
            f"python train.py -m algo=sweep/penalty algo.penalty=2.0 env.start=0.1 seed=1 +experiment=x hydra.sweep.dir={sweep / 'penalty' / 'rerun'}",
            f"python train.py -m algo=sweep/ppo_lag algo.cost_limit=0.5 'env.start=[0.0,1.0]' seed=1 +experiment=x hydra.sweep.dir={sweep / 'constraint' / 'rerun'}",
        ]
    )

    answers = (out / "answers.md").read_text()
    assert "lambda* = 1.3643" in answers and "a drop of 0.500 at λ = 1.3643" in answers
    assert (out / "penalty_vs_constraint.png").stat().st_size > 10_000
    assert "| penalty | λ=2 | x0=0.1 | 2/3 | 0.300 ± 0.141 | 0.000 ± 0.000 |" in (out / "table.md").read_text()


def test_an_empty_directory_is_reported_not_a_crash(tmp_path, capsys):
    assert pvc.main([str(tmp_path), "--out", str(tmp_path / "r")]) == 0
    assert "0 ok, 0 failed, 0 incomplete, 0 missing" in capsys.readouterr().out
    assert (tmp_path / "r" / "penalty_vs_constraint.png").is_file()
