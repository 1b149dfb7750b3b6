"""The penalty thresholds of Reach1D from dynamic programming, against hand-derived values and
against brute-force value iteration on r - lambda * c."""

import numpy as np
import pytest

from cmdp_rl.envs.reach1d_task import Reach1DConfig
from cmdp_rl.envs.reach1d_dp import closed_form_threshold, crossing_thresholds, penalized_crosses

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
