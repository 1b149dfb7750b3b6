"""The penalty thresholds of Reach1D from dynamic programming, against hand-derived values and
against brute-force value iteration on r - lambda * c."""

import numpy as np
import pytest

from cmdp_rl.envs.reach1d.optimum import constrained_optimum
from cmdp_rl.envs.reach1d.task import Reach1DConfig
from lab.studies.reach1d_thresholds import closed_form_threshold, crossing_thresholds, penalized_crosses

PASS = Reach1DConfig(wall="pass")


def by_hand(g):
    # From the wall: 4 moves of 0.1 reach the goal band (+1 on the 4th); stopping is worth 0.
    return 0.1 * (1 + g + g**2 + g**3) + g**3


@pytest.mark.parametrize("gamma", [0.99, 0.9])
def test_seed_start_threshold_is_the_hand_derived_value(gamma):
    th = crossing_thresholds(PASS, gamma)
    assert th.at(0.1) == pytest.approx(by_hand(gamma), abs=1e-9)
    assert closed_form_threshold(PASS, gamma) == pytest.approx(by_hand(gamma), abs=1e-12)


def test_undiscounted_threshold_is_progress_beyond_the_wall_plus_the_bonus():
    # 1.8 - lambda against 0.4 (the grid leaves the stopping plan 0.001 short of the wall)
    assert crossing_thresholds(PASS, 1.0).at(0.1) == pytest.approx(1.4, abs=2e-3)


def test_thresholds_agree_with_brute_force_value_iteration():
    th = crossing_thresholds(PASS, 0.99)
    left = th.x < PASS.wall_x
    lam = th.at(0.1)
    below, above = penalized_crosses(PASS, lam - 0.01, 0.99), penalized_crosses(PASS, lam + 0.01, 0.99)
    assert below[left].all() and not below[~left].any()
    assert not above.any()
    np.testing.assert_allclose(th.threshold[left], lam, atol=1e-9)  # the same for every left start
    assert (th.threshold[~left] == 0).all()


def test_blocking_wall_never_pays():
    assert crossing_thresholds(Reach1DConfig(wall="block"), 0.99).threshold.max() == 0.0


def test_expected_cost_is_a_step_function_of_the_penalty():
    th = crossing_thresholds(PASS, 0.99)
    lam = th.at(0.1)
    np.testing.assert_allclose(th.expected_cost(0.1, [0.0, lam - 1e-6, lam + 1e-6, 5.0]), [1, 1, 0, 0])
    np.testing.assert_allclose(th.expected_cost([0.0, 1.0], [0.0, lam - 1e-6, lam + 1e-6]), [0.5, 0.5, 0.0])
    assert th.jumps([0.0, 1.0]) == [(pytest.approx(lam), pytest.approx(0.5))]
    assert th.jumps([0.6, 1.0]) == []


# --- the constrained optimum (undiscounted, as eval.json reports return and cost) ------------------
# From x0 = 0.1 the return telescopes to (0.9 - x0) - (distance left) (+1 at the goal). On the grid
# the best stop short of the wall is x = 0.499: 0.399. Crossing (wall=pass) and landing on the goal:
# 0.8 + 1 = 1.8, for one crossing.


def test_blocking_wall_optimum_is_stopping_just_short_of_the_wall():
    for d in (0.0, 1.0, 5.0):
        opt = constrained_optimum(Reach1DConfig(), d)
        assert opt.value == pytest.approx(0.399, abs=1e-9)
        assert opt.cost == 0.0


@pytest.mark.parametrize(
    "d, value", [(0.0, 0.399), (0.25, 0.75 * 0.399 + 0.25 * 1.8), (0.5, 1.0995), (1.0, 1.8), (3.0, 1.8)]
)
def test_passable_wall_optimum_mixes_stopping_and_crossing(d, value):
    # The budget buys the crossing plan with probability min(d, 1): a randomised policy.
    opt = constrained_optimum(PASS, d)
    assert opt.value == pytest.approx(value, abs=1e-9)
    assert opt.cost == pytest.approx(min(d, 1.0))
    if 0 < d < 1:  # the tie: each crossing is worth 0.401 of progress plus the +1
        assert opt.penalty == pytest.approx(1.401, abs=1e-9)


def test_optimum_from_a_uniform_start_by_hand():
    # x0 ~ U[0, 1] as the grid's 1000 cells x0 = 0.000 ... 0.999. Left of the wall (half the mass):
    # stopping at 0.499 earns 0.499 - x0 (mean 0.2495), crossing 1.401 more for every start. Right of
    # it: |0.9 - x0| + 1 at no cost (mean of |0.9 - x0| over 0.500..0.999: (80.2 + 4.95) / 500).
    # Uncrossed value 0.5 * 0.2495 + 0.5 * (85.15 / 500 + 1) = 0.7099; each unit of budget spent on
    # left starts buys 1.401, up to all of them (0.5).
    base = 0.5 * 0.2495 + 0.5 * (85.15 / 500 + 1)
    env = Reach1DConfig(wall="pass", start=[0.0, 1.0])
    assert constrained_optimum(env, 0.25).value == pytest.approx(base + 0.25 * 1.401, abs=1e-9)
    full = constrained_optimum(env, 1.0)
    assert full.value == pytest.approx(base + 0.5 * 1.401, abs=1e-9)
    assert full.cost == pytest.approx(0.5) and full.penalty == 0.0


def test_optimum_rejects_a_negative_budget():
    with pytest.raises(ValueError, match="cost_limit"):
        constrained_optimum(PASS, -1.0)


def test_env_options_expose_the_optimum():
    assert Reach1DConfig().optimum(1.0) == pytest.approx(0.399)
    assert PASS.optimum(0.5) == pytest.approx(1.0995)
