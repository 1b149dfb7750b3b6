"""The analysis the experiment scripts apply to a run's metrics, on hand-made sequences."""

import importlib
import math
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(name):
    return importlib.import_module(f"lab.studies.{name}")


def test_damping_metrics_measure_after_the_first_crossing_of_the_budget():
    pid = _load("pid_damping")
    cost = np.array([3.0, math.nan, 0.0, 0.0, 1.0, 2.0, 0.5, 0.2])  # a batch without episodes: nan
    m = pid.damping_metrics(cost, d=0.5)
    after = np.array([-0.5, -0.5, 0.5, 1.5, 0.0, -0.3])  # from iteration 3, the first at or below d
    assert m["first_crossing"] == 3
    assert m["overshoot"] == pytest.approx(1.5)
    assert m["overshoot_smooth"] == pytest.approx(max(after[:5].mean(), after[1:].mean()))
    assert m["violation"] == pytest.approx(2.0 / 6)
    assert m["oscillation"] == pytest.approx(3.3 / 6)
    assert math.isnan(pid.damping_metrics(np.array([2.0, 1.0, 0.9]), d=0.5)["overshoot"])  # never crossed
