"""The generated suite's study (lab/studies/cmdp_suite.py): its step budget, its verdicts (2% slack on
each budget, 90% of J*), a table that never pools tuning and held-aside instances, one real run judged
exactly and consistent with the run's own evaluation episodes, and a refusal recorded once."""

import json
import math

import pytest

from cmdp_rl.envs.suite.model import generate, solve
from lab.studies.cmdp_suite import (
    NEAR,
    SLACK,
    SuiteRun,
    parse_ids,
    run_one,
    run_population,
    split_of,
    step_budget,
    table,
)


def judged(ret: float, costs: list[float], instance: int = 0, algo: str = "ppo_lag", seed: int = 0) -> SuiteRun:
    return SuiteRun(
        instance, algo, seed, split_of(instance), 1, 10, len(costs), 1.0, [1.0] * len(costs), "mixed", True,
        10.0, [1.0] * len(costs), ret=ret, costs=costs,
    )  # fmt: skip


def test_the_step_budget_is_episodes_of_the_horizon_with_a_floor():
    assert step_budget(200, episodes=2000, min_steps=102_400) == 400_000
    assert step_budget(10, episodes=2000, min_steps=102_400) == 102_400
    assert step_budget(60, episodes=100, min_steps=0) == 6000


def test_the_verdict_allows_two_percent_over_each_budget_and_asks_ninety_percent_of_j_star():
    assert judged(10 * NEAR, [1.0 + SLACK, 0.5]).success
    over = judged(10.0, [1.0, 1.0 + 1.5 * SLACK])
    assert not over.within and over.near and over.verdict == f"over budget: cost_1 {1 + 1.5 * SLACK:.2f} x d"
    short = judged(10 * NEAR - 0.01, [0.2])
    assert short.within and not short.near and short.verdict == f"return {(10 * NEAR - 0.01) / 10:.0%} of J*"


def test_the_table_reports_tuning_and_held_aside_apart_and_leaves_refusals_out_of_the_rates():
    refused = judged(math.nan, [], instance=1001)
    refused.refused = "cpo takes one constraint"
    runs = [judged(10.0, [0.5], 0), judged(5.0, [0.5], 1), judged(10.0, [0.5], 1000), refused]
    rows = {line.split("|")[2].strip(): line for line in table(runs).splitlines()[2:]}
    assert set(rows) == {"tuning", "held-aside"}
    assert "| 2 | 0 | 2/2 (100%) | 1/2 (50%) | 1/2 (50%) |" in rows["tuning"]
    assert "| 1 | 1 | 1/1 (100%) | 1/1 (100%) | 1/1 (100%) |" in rows["held-aside"]


def test_instance_ranges_parse_and_bad_ones_stop_in_one_line():
    assert parse_ids(["0-2", "1000", "7-7"]) == [0, 1, 2, 1000, 7]
    with pytest.raises(SystemExit, match=r"^--instances: expected N or N-M .*got '-3'$"):
        parse_ids(["-3"])


def test_one_run_is_judged_exactly_and_agrees_with_its_own_evaluation(tmp_path):
    run = run_one(1, "ppo_lag", 0, tmp_path / "run", episodes=1, min_steps=4096)
    result = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert run.refused is None and run.steps == 4096 and result["steps"] == 4096
    assert run.optimum == pytest.approx(solve(generate(1)).ret)  # J* at the instance's own budget
    # the exact values of the deployed policy against the run's own 200 sampled evaluation episodes
    se = result["episode_return_std"] / math.sqrt(result["episodes"])
    assert abs(run.ret - result["episode_return"]) < 5 * se
    se_cost = result["episode_cost_std"] / math.sqrt(result["episodes"])
    assert abs(run.costs[0] - result["episode_cost"]) < 5 * se_cost
    assert run.multipliers is not None and len(run.multipliers) == 1


def test_a_refusal_is_recorded_once_and_read_back(tmp_path):
    first = run_one(0, "cpo", 0, tmp_path / "run")  # instance 0 has 3 costs; cpo takes one
    assert first.refused is not None and "one constraint" in first.refused
    assert (tmp_path / "run" / "refused.txt").read_text().strip() == first.refused
    assert run_one(0, "cpo", 0, tmp_path / "run").refused == first.refused


def test_seeds_as_one_population_are_judged_each_on_its_own(tmp_path):
    """--population: one population job for an instance's seeds, each seed judged on its own agent's run."""
    runs = run_population(1, "ppo_lag", [0, 1], tmp_path / "pop", episodes=1, min_steps=4096)
    assert [r.seed for r in runs] == [0, 1] and all(r.refused is None and r.steps == 4096 for r in runs)
    assert all(r.optimum == pytest.approx(solve(generate(1)).ret) and len(r.costs) == 1 for r in runs)
    assert runs[0].ret != runs[1].ret  # two seeds, two policies
