"""The end-of-run summary: the gap to the optimum, each budget's verdict, and what it says of the goal."""

import pytest

from cmdp_rl.envs.reach1d.task import Reach1DConfig
from cmdp_rl.report.summary import Constraint, constraint_line, summary_lines


def result(ret=0.38, cost=0.0, goal=0.0):
    return {
        "episodes": 20,
        "episode_return": ret,
        "episode_return_std": 0.01,
        "episode_cost": cost,
        "episode_cost_std": 0.05,
        "goal_reached": goal,
    }


class Solvable:
    """An env's options with a known optimum and no goal."""

    def optimum(self, cost_limit):
        return 0.4 if cost_limit >= 1 else 0.2


class NoSolver:
    termination_metric = "goal_reached"


def test_gap_to_the_optimum_by_hand():
    lines = summary_lines(result(ret=0.38), Solvable(), 1.0, header="done")
    assert lines[0] == "done | eval over 20 episodes:"
    # 0.4 - 0.38 = 0.02, 5.0% of 0.4
    assert lines[1] == "  return 0.380 ± 0.010 | constrained optimum 0.400 (exact solver) | gap 0.020 (5.0% of it)"
    assert len(lines) == 3  # no goal line: this task has no termination metric
    # the optimum at the run's own budget
    assert "constrained optimum 0.200" in summary_lines(result(), Solvable(), 0.5, header="done")[1]


def test_no_solver_no_optimum_and_a_goal_fraction():
    lines = summary_lines(result(goal=0.35), NoSolver(), 1.0, header="done")
    assert lines[1] == "  return 0.380 ± 0.010"
    assert lines[-1] == "  goal reached in 35% of episodes"


def test_over_budget_verdict():
    assert (
        constraint_line(Constraint("cost", 1.5, 0.5, 1.0)) == "cost 1.50 ± 0.50 against budget 1: over budget by 0.50"
    )
    assert constraint_line(Constraint("cost", 1.0, 0.0, 1.0)).endswith(": within budget")  # d is allowed
    lines = summary_lines(result(cost=2.25), Solvable(), 1.0, header="done")
    assert lines[2] == "  cost 2.25 ± 0.05 against budget 1: over budget by 1.25"


def test_reach1d_blocking_wall_says_out_of_reach_not_zero_percent():
    lines = summary_lines(result(ret=0.38), Reach1DConfig(), 1.0, header="done")
    text = "\n".join(lines)
    assert "constrained optimum 0.399 (exact solver) | gap 0.019 (4.8% of it)" in text  # 0.019 / 0.399
    assert "goal out of reach by design" in text and "env.wall=block" in text
    assert "goal reached" not in text and "0%" not in text.replace("4.8%", "")


@pytest.mark.parametrize("env", [Reach1DConfig(wall="pass"), Reach1DConfig(start=[0.0, 1.0]), Reach1DConfig(goal=0.51)])
def test_reach1d_goal_fraction_where_the_goal_can_be_reached(env):
    # passable wall; starts on the goal's side; a goal within its tolerance of the wall
    lines = summary_lines(result(goal=0.6), env, 1.0, header="done", optimum=1.0)
    assert lines[-1] == "  goal reached in 60% of episodes"
