"""Statistics of a few seeds' results, and of a run's last iterations."""

from __future__ import annotations

import math
import statistics
from typing import Iterable, Sequence

import numpy as np


def sample_mean_std(values: Iterable[float], skip_nonfinite: bool = True) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof=1) over seeds; the std is nan for a single value
    (one seed says nothing about the spread) and both are nan for none. ``skip_nonfinite``: leave
    out nan/inf values (a seed without the measurement) rather than let them make the mean nan."""
    v = np.array(list(values), dtype=float)
    if skip_nonfinite:
        v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else math.nan


def population_mean_std(values: Sequence[float]) -> tuple[float | None, float | None]:
    """Mean and population standard deviation (ddof=0; 0 for a single value), both computed with
    exact summation (``statistics``); ``(None, None)`` for no values."""
    if not values:
        return None, None
    return statistics.fmean(values), (statistics.pstdev(values) if len(values) > 1 else 0.0)


def count_finite(values: Iterable[float]) -> int:
    """How many of ``values`` are finite (the seeds a mean was taken over)."""
    return int(np.isfinite(np.array(list(values), dtype=float)).sum())


def tail_mean(values: Sequence[float], fraction: float) -> float:
    """Mean of the finite values among the last ``fraction`` of ``values`` (at least one entry):
    e.g. the training cost over the last quarter of iterations, the average late iterate. nan if
    none is finite."""
    if not len(values):
        return math.nan
    tail = np.array(values[-max(1, int(round(len(values) * fraction))) :], dtype=float)
    tail = tail[np.isfinite(tail)]
    return float(tail.mean()) if tail.size else math.nan
