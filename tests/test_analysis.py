"""The report pieces in lab.studies and the sweep readers they use, on hand-computed values."""

import json
import math

import numpy as np
import pytest
import yaml

from cmdp_rl.report.sweeps import FAILED, MISSING, OK
from lab.studies.penalty_constraint import (
    GroupKey,
    Run,
    from_missing,
    group_key,
    start_label,
    table_markdown,
    table_rows,
)
from lab.studies.stats import count_finite, population_mean_std, sample_mean_std, tail_mean
from lab.studies.tables import markdown_table, pm, write_csv
from lab.sweeps import MissingJob, finished_runs, job_values, read_sweeps, started_runs


def test_sample_mean_std_is_over_finite_seeds_with_ddof_1():
    mean, std = sample_mean_std([1.0, 2.0, 4.0])
    assert mean == pytest.approx(7 / 3)
    assert std == pytest.approx(math.sqrt((16 / 9 + 1 / 9 + 25 / 9) / 2))  # deviations -4/3, -1/3, 5/3
    assert sample_mean_std([1.0, math.nan, 3.0, math.inf]) == (2.0, pytest.approx(math.sqrt(2)))
    single = sample_mean_std([5.0])
    assert single[0] == 5.0 and math.isnan(single[1])  # one seed: no spread
    assert all(math.isnan(x) for x in sample_mean_std([]))
    assert math.isnan(sample_mean_std([1.0, math.nan], skip_nonfinite=False)[0])


def test_population_mean_std_has_ddof_0_and_none_for_no_values():
    mean, std = population_mean_std([1.0, 2.0, 4.0])
    assert mean == pytest.approx(7 / 3) and std == pytest.approx(math.sqrt(42 / 9 / 3))
    assert population_mean_std([5.0]) == (5.0, 0.0)
    assert population_mean_std([]) == (None, None)
    assert population_mean_std([1e16, 1.0, -1e16]) == (1 / 3, pytest.approx(math.sqrt(2) * 1e16 / math.sqrt(3)))


def test_tail_mean_and_count_finite():
    assert tail_mean([0.0, 1, 2, 3, 4, 5, 6, 7], 0.25) == 6.5  # the last 2 of 8
    assert tail_mean([1.0, 2.0, math.nan, 4.0], 0.5) == 4.0  # nan left out of the last 2
    assert tail_mean([3.0, 5.0], 0.1) == 5.0  # at least one entry
    assert math.isnan(tail_mean([1.0, math.nan], 0.5)) and math.isnan(tail_mean([], 0.25))
    assert count_finite([1.0, math.nan, math.inf, 2.0]) == 2


def test_pm_cells():
    assert pm(1.23456, 0.5) == "1.235 ± 0.500"
    assert pm(1.0, math.nan) == "1.000" and pm(1.0) == "1.000"  # no std: the mean alone
    assert pm(None, None) == "n/a" and pm(math.nan, 1.0, missing="never") == "never"
    assert pm(1234.5, 12.3, ".3g", ".2g") == "1.23e+03 ± 12"
    assert pm(27062.4, 6839.1, ",.0f") == "27,062 ± 6,839"
    assert pm(None, None, ".2f", missing="") == ""


def test_markdown_table_and_csv(tmp_path):
    assert markdown_table(["a", "b"], [["x", "1"], ["y", ""]], "lr") == "| a | b |\n|---|---:|\n| x | 1 |\n| y |  |"
    assert markdown_table(["a"], []) == "| a |\n|---|"
    with pytest.raises(ValueError, match="align has 1 letters for 2 columns"):
        markdown_table(["a", "b"], [], "l")
    write_csv(tmp_path / "t.csv", [{"a": 1, "b": 0.5}, {"a": 2, "b": math.nan}])
    assert (tmp_path / "t.csv").read_bytes() == b"a,b\r\n1,0.5\r\n2,nan\r\n"
    write_csv(tmp_path / "e.csv", [])
    assert (tmp_path / "e.csv").read_text() == ""


def test_groups_of_a_penalty_constraint_study():
    assert start_label(0.1) == "x0=0.1" and start_label([0.0, 1.0]) == "x0~U[0,1]"
    assert start_label([0.3, 0.3]) == "x0=0.3" and start_label(None) == "x0=?"
    assert group_key("ppo", None, 0.5, 0.1) == GroupKey("ppo", "lambda", 0.0, "x0=0.1")  # ppo: lambda = 0
    assert group_key("penalty", 2, None, 0.1) == GroupKey("penalty", "lambda", 2.0, "x0=0.1")
    assert group_key("cpo", None, "0.25", [0, 1]) == GroupKey("cpo", "d", 0.25, "x0~U[0,1]")
    assert group_key("cpo", None, None, 0.1) is None and group_key(None, 1, 1, 0.1) is None
    missing = from_missing(
        MissingJob(
            __import__("pathlib").Path("/s"),
            ["algo=sweep/ppo_lag", "algo.cost_limit=0.5", "env.start=[0.0,1.0]", "seed=1"],
        )
    )
    assert (missing.key, missing.status, missing.seed) == (GroupKey("ppo_lag", "d", 0.5, "x0~U[0,1]"), MISSING, 1)


class _Reference:  # a made-up env: crossing pays below lambda = 1, and 60 % of the starts cross
    starts = {"x0=0.1": 0.1}

    def predicted_cost(self, start_lbl, penalty):
        return 0.6 if penalty < 1 else 0.0

    def unconstrained_cost(self, start_lbl):
        return 0.6


def test_table_rows_compare_the_seeds_with_the_reference():
    pen = GroupKey("penalty", "lambda", 0.5, "x0=0.1")
    con = GroupKey("ppo_lag", "d", 1.0, "x0=0.1")
    runs = [
        Run(pen, OK, "a", [], eval_return=1.0, eval_cost=0.5, train_cost=0.7, final_lambda=0.5),
        Run(pen, OK, "b", [], eval_return=2.0, eval_cost=1.0, train_cost=0.9, final_lambda=0.5),
        Run(pen, FAILED, "c", []),
        Run(con, OK, "d", [], eval_return=3.0, eval_cost=0.62, train_cost=0.5, final_lambda=2.0),
    ]
    pen_row, con_row = table_rows(runs, _Reference())
    assert (pen_row["runs_ok"], pen_row["runs"]) == (2, 3)
    assert pen_row["return_mean"] == 1.5 and pen_row["return_std"] == pytest.approx(math.sqrt(0.5))
    assert pen_row["cost_mean"] == 0.75 and pen_row["predicted_cost"] == 0.6
    assert pen_row["check"] == "agrees"  # |0.75 - 0.6| <= 0.25
    assert con_row["predicted_cost"] == 0.6  # min(d = 1, the unconstrained 0.6)
    assert con_row["check"] == "meets d" and math.isnan(con_row["cost_std"])
    lines = table_markdown([pen_row, con_row]).splitlines()
    assert lines[1] == "|---|---:|---|---:|---:|---:|---:|---:|---:|---|"
    assert lines[2] == (
        "| penalty | λ=0.5 | x0=0.1 | 2/3 | 1.500 ± 0.707 | 0.750 ± 0.354 | 0.800 ± 0.141 | 0.50 | 0.60 | agrees |"
    )
    assert lines[3] == "| ppo_lag | d=1 | x0=0.1 | 1/1 | 3.000 | 0.620 | 0.500 | 2.00 | 0.60 | meets d |"
    assert table_rows(runs, None)[0]["check"] == "" and math.isnan(table_rows(runs, None)[0]["predicted_cost"])


def test_job_values_reads_overrides_as_yaml():
    assert job_values(["algo=sweep/penalty", "+env.start=[0.0,1.0]", "seed=2", "~x=y", "bad=[1,"]) == {
        "algo": "sweep/penalty",
        "env.start": [0.0, 1.0],
        "seed": 2,
        "x": "y",
        "bad": "[1,",
    }


def _run_dir(d, overrides, finished=True, started=True):
    (d / ".hydra").mkdir(parents=True)
    (d / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    if started:
        (d / "metrics.csv").write_text("step,episode_cost\n1,0.5\n")
    if finished:
        (d / "eval.json").write_text(json.dumps({"episode_return": 1.0}))


def test_sweep_readers(tmp_path):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    params = {"seed": "0,1,2"}
    (sweep / "multirun.yaml").write_text(yaml.safe_dump({"hydra": {"sweeper": {"params": params}}}))
    _run_dir(sweep / "0", ["seed=0"])
    _run_dir(sweep / "1", ["seed=1"], finished=False)
    _run_dir(sweep / "rerun" / "0", ["seed=1"])  # seed 1 ran again and finished
    assert [r.path.name for r in finished_runs(sweep)] == ["0"]  # one level down only
    assert [r.path.name for r in started_runs(sweep)] == ["0", "1"]
    records, missing = read_sweeps([sweep])
    assert {str(r.path.relative_to(sweep)): r.status for r in records} == {"0": OK, "1": "superseded", "rerun/0": OK}
    assert missing == [MissingJob(sweep, ["seed=2"])]
    assert np.isclose(records[0].metrics[0]["episode_cost"], 0.5)
