"""The deploy-rule study on the generated suite (lab/studies/suite_deploy_rules.py): from one finished run it values
every snapshot exactly, chooses the run's own weights again at the run's own margin, and judges the deployed mixture
as the suite's study does."""

import numpy as np
import pytest

from lab.studies.cmdp_suite import run_one
from lab.studies.suite_deploy_rules import ceiling, feasible_weights, load_snapshots, table, verdict

MIXTURE = ["deploy.policy=mixture", "deploy.snapshots=4", "deploy.episodes=8"]


def test_a_run_is_chosen_again_and_judged_as_the_study_judges_it(tmp_path):
    run = run_one(1, "ppo_lag", 0, tmp_path / "run", episodes=1, min_steps=16384, extra=MIXTURE)  # 8 iterations
    found = load_snapshots(tmp_path / "run", revalue=8)
    assert found is not None and found.instance == 1 and len(found.exact_ret) == len(found.measured) == 4
    assert len(found.fresh) == 4 and all(v.episodes >= 8 for v in found.fresh)
    # the run's own values at its own margin (3): the weights it deployed
    again, _ = feasible_weights(found.measured, found.budgets, 3.0)
    assert again == pytest.approx(found.deployed, abs=1e-9)
    # the deployed mixture's exact values are the study's
    w = np.asarray(found.deployed)
    assert float(w @ found.exact_ret) == pytest.approx(run.ret, rel=1e-9)
    assert (w @ found.exact_costs).tolist() == pytest.approx(run.costs, rel=1e-9)
    assert verdict(found, found.deployed) == (run.within, run.near)
    assert not run.success or ceiling(found)  # a mixture that succeeds is one the ceiling has
    lines = table([found], [0.0, 3.0]).splitlines()
    assert "tuning: 1 runs" in lines and any(line.startswith("| ceiling (exact values) |") for line in lines)


def test_a_run_that_deployed_its_last_iterate_is_left_out(tmp_path):
    run_one(1, "ppo_lag", 0, tmp_path / "run", episodes=1, min_steps=4096, extra=["deploy.policy=last"])
    assert load_snapshots(tmp_path / "run") is None
