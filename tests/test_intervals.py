"""cmdp_rl.report.intervals: exact binomial bounds against closed forms and published values, the bootstrap
against the normal-theory interval, reproducibility, and the degenerate samples a real evaluation
gives (every episode alike, one episode)."""

import json
import math
import warnings

import numpy as np
import pytest
from scipy import stats

from cmdp_rl.report.intervals import (
    episodes_for_violation_bound,
    mean_interval,
    summarize,
    summary_lines,
    violation_interval,
)


def test_no_violation_bounds_have_the_closed_form():
    # With k = 0 the Clopper-Pearson upper bound solves (1 - p)**n = alpha: 1 - alpha**(1/n).
    for n in (1, 20, 100):
        v = violation_interval([0.0] * n, cost_limit=1.0)
        assert v["violations"] == 0 and v["rate"] == 0 and v["low"] == 0
        assert v["upper"] == pytest.approx(1 - 0.05 ** (1 / n), rel=1e-9)  # one-sided 95%
        assert v["high"] == pytest.approx(1 - 0.025 ** (1 / n), rel=1e-9)  # two-sided 95%
    assert violation_interval([0.0] * 20, 1.0)["upper"] == pytest.approx(0.1391, abs=1e-4)
    assert violation_interval([0.0] * 100, 1.0)["upper"] == pytest.approx(0.0295, abs=1e-4)
    # all n episodes violate: the lower end is alpha/2 ** (1/n), the upper one is 1
    v = violation_interval([2.0] * 10, cost_limit=1.0)
    assert v["rate"] == 1 and v["high"] == 1 and v["low"] == pytest.approx(0.025 ** (1 / 10), rel=1e-9)


def test_clopper_pearson_matches_the_published_table_value():
    # 1 success in 10 trials: exact 95% interval [0.0025, 0.4450] (Clopper and Pearson's charts;
    # the same figures appear in standard binomial tables).
    v = violation_interval([3.0] + [0.0] * 9, cost_limit=0.5)
    assert v["violations"] == 1 and v["rate"] == 0.1
    assert v["low"] == pytest.approx(0.00253, abs=1e-5) and v["high"] == pytest.approx(0.44502, abs=1e-5)


def test_a_violation_is_cost_strictly_above_the_budget_up_to_rounding():
    costs = [0.0, 1.0, 1.5, 2.0, 0.1 + 0.2]  # 0.30000000000000004 against d = 0.3 is not over
    assert violation_interval(costs, 1.0)["violations"] == 2
    assert violation_interval(costs, 0.3)["violations"] == 3


def test_bootstrap_interval_covers_the_mean_and_agrees_with_the_normal_interval():
    x = np.random.default_rng(3).normal(2.0, 0.5, size=400)
    r = mean_interval(x)
    half = 1.96 * x.std(ddof=1) / math.sqrt(x.size)  # normal-theory half-width, fine at n = 400
    assert r["low"] < r["mean"] < r["upper"] < r["high"]
    assert r["mean"] == pytest.approx(x.mean())
    assert r["high"] - r["low"] == pytest.approx(2 * half, rel=0.1)
    assert r["upper"] - r["mean"] == pytest.approx(1.645 / 1.96 * half, rel=0.1)  # one-sided 95%
    assert not r["no_spread"] and "method" not in r


def test_bootstrap_is_reproducible_with_its_seed():
    x = np.random.default_rng(0).exponential(1.0, size=30)
    a, b, c = mean_interval(x, seed=5), mean_interval(x, seed=5), mean_interval(x, seed=6)
    assert a == b
    assert (a["low"], a["high"]) != (c["low"], c["high"])


def test_skewed_cost_gets_an_asymmetric_interval():
    # 2 of 20 episodes collided once: the mean 0.1 cannot go below 0, and its interval reaches
    # further up than down (what BCa is for).
    r = mean_interval([1.0, 1.0] + [0.0] * 18)
    assert 0 <= r["low"] < 0.1 < r["upper"] < r["high"]
    assert r["high"] - 0.1 > 0.1 - r["low"]


def test_every_episode_alike_gives_the_value_itself_and_says_so():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no NaN, no division warnings
        r = mean_interval([0.0] * 20)
    assert (r["low"], r["high"], r["upper"], r["no_spread"]) == (0.0, 0.0, 0.0, True)
    s = summarize([0.4] * 20, [0.0] * 20, cost_limit=1.0)
    assert s["episode_cost_ci95"] == [0.0, 0.0] and s["intervals"]["no_spread"] == ["episode_return", "episode_cost"]
    assert s["violation_rate_ucb95"] == pytest.approx(0.1391, abs=1e-4)
    lines = summary_lines({"episodes": 20, "episode_return": 0.4, "episode_cost": 0.0, **s}, 1.0)
    assert "rest a safety claim on the violation bound" in lines[1]
    assert lines[2] == "violations 0/20 episodes (cost > 1): rate 0%, 95% CI [0%, 17%], 95% upper bound 14%"


def test_one_episode_has_no_mean_interval_but_a_violation_bound():
    s = summarize([0.3], [0.0], cost_limit=0.5)
    assert s["episode_return_ci95"] is None and s["episode_cost_ci95"] is None and s["episode_cost_ucb95"] is None
    assert s["violation_rate_ci95"] == [0.0, pytest.approx(0.975)] and s["violation_rate_ucb95"] == pytest.approx(0.95)
    json.dumps(s, allow_nan=False)  # JSON-clean: null, not NaN
    lines = summary_lines({"episodes": 1, "episode_return": 0.3, "episode_cost": 0.0, **s}, 0.5)
    assert "no interval (1 episode)" in lines[0] and "no interval (1 episode)" in lines[1]


def test_summarize_names_its_method_and_is_json_clean():
    rng = np.random.default_rng(1)
    s = summarize(rng.normal(0.35, 0.01, 20), (rng.random(20) < 0.2).astype(float), cost_limit=0.5)
    json.dumps(s, allow_nan=False)
    assert s["intervals"]["level"] == 0.95 and s["intervals"]["seed"] == 0 and s["intervals"]["resamples"] == 9999
    assert "BCa" in s["intervals"]["method"] and "Clopper-Pearson" in s["intervals"]["violation_method"]
    assert s["episode_cost_ci95"][0] <= s["episode_cost_ucb95"] <= s["episode_cost_ci95"][1]
    assert s["violation_rate_ci95"][0] <= s["violation_rate"] <= s["violation_rate_ucb95"]


def test_episodes_needed_for_a_violation_bound():
    assert episodes_for_violation_bound(0.05) == 59  # the "rule of three": about 3/0.05 = 60
    for bound in (0.03, 0.05, 0.1, 0.14):
        n = episodes_for_violation_bound(bound)
        ucb = lambda m: stats.binomtest(0, m, alternative="less").proportion_ci(0.95).high  # noqa: E731
        assert ucb(n) <= bound < ucb(n - 1)
    with pytest.raises(ValueError):
        episodes_for_violation_bound(0.0)


def test_empty_sample_is_an_error():
    with pytest.raises(ValueError):
        mean_interval([])
    with pytest.raises(ValueError):
        violation_interval([], 1.0)
