"""Comparisons within a tolerance: two code paths, or numbers recorded on another CPU (docs/testing.md,
"Exact, or within a tolerance"). Each tolerance is a :class:`Tolerance` written beside its test with
the reason for its size.

With ``CMDP_RL_MARGINS=<file>`` in the environment (``make test-cpus`` sets it), every comparison
appends the share of its tolerance that its largest difference used: the rerun under each CPU
setting then says how much room each tolerance has left.
"""

from __future__ import annotations

import json
import math
import os
from typing import NamedTuple

import numpy as np


class Tolerance(NamedTuple):
    """``|a - b| <= max(rel * max(|a|, |b|), abs)`` for each pair of numbers (``math.isclose``'s test)."""

    name: str
    rel: float
    abs: float


def share(a, b, tol: Tolerance) -> float:
    """The largest share of ``tol`` that a difference between ``a`` and ``b`` uses (arrays or numbers,
    NaN equal to NaN); above 1 they are not within it."""
    a, b = (np.asarray(x.detach().cpu() if hasattr(x, "detach") else x, dtype=np.float64) for x in (a, b))
    a, b = np.broadcast_arrays(a, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        diff = np.where((np.isnan(a) & np.isnan(b)) | (a == b), 0.0, np.abs(a - b))  # a == b: equal infinities too
        room = np.maximum(tol.rel * np.maximum(np.abs(a), np.abs(b)), tol.abs)
        used = np.where(diff == 0, 0.0, diff / room)
    used = np.where(np.isnan(used), math.inf, used)  # NaN against a number, or an infinity against another
    return float(used.max()) if used.size else 0.0


def record(tol: Tolerance, used: float) -> None:
    """Append ``used`` to the margins file, if one is asked for."""
    path = os.environ.get("CMDP_RL_MARGINS")
    if path:
        test = os.environ.get("PYTEST_CURRENT_TEST", "?").rsplit(" (", 1)[0]
        with open(path, "a") as f:
            f.write(json.dumps({"tolerance": tol.name, "test": test, "share": used}) + "\n")


def assert_close(a, b, tol: Tolerance, what: str = "") -> None:
    """``a`` within ``tol`` of ``b``, element by element (same shapes)."""
    assert np.shape(a) == np.shape(b), f"{what}: shapes {np.shape(a)} and {np.shape(b)}"
    used = share(a, b, tol)
    record(tol, used)
    assert used <= 1.0, f"{what}: beyond {tol} ({used:.3g} of it)\n{np.asarray(a)!r}\n{np.asarray(b)!r}"
