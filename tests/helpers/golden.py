"""The numbers recorded in ``tests/golden/`` and how a run's outputs are compared with them (tests/test_golden.py
says why another machine's recording may differ in its last bits, and how far)."""

import math
import os
import re
from pathlib import Path

import torch

from helpers.runs import eval_result, metrics_rows

GOLDEN = Path(__file__).resolve().parents[1] / "golden"
WRITE = os.environ.get("CMDP_RL_WRITE_GOLDEN") == "1"


def outputs(run_dir: Path) -> dict:
    res = eval_result(run_dir)
    res.pop("torch_threads", None)
    return {"metrics": metrics_rows(run_dir), "eval": res}


def machine() -> str:
    """CPU model and the SIMD level torch uses: what decides the order of float sums here."""
    model = "unknown-cpu"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return re.sub(r"[^A-Za-z0-9]+", "-", model).strip("-") + "_" + torch.backends.cpu.get_cpu_capability()


def mismatch(got: dict, want: dict, close: bool) -> str | None:
    """First difference between two outputs (``None`` if none); ``close`` compares numbers with
    the cross-machine tolerance instead of exactly."""

    def same(g, w) -> bool:
        if g == w:
            return True
        if not close:
            return False
        try:
            return math.isclose(float(g), float(w), rel_tol=1e-2, abs_tol=1e-6)
        except (TypeError, ValueError):
            return False

    for k, w in want["eval"].items():
        if not same(got["eval"].get(k), w):
            return f"eval.json {k}: {got['eval'].get(k)} != {w}"
    if len(got["metrics"]) != len(want["metrics"]):
        return f"metrics.csv has {len(got['metrics'])} rows, recorded {len(want['metrics'])}"
    # Columns another algorithm fills were blank in the recorded file; since each algorithm writes
    # only the statistics it declares, they may now be absent. Every recorded number must match.
    for i, (g, w) in enumerate(zip(got["metrics"], want["metrics"])):
        diff = {k: (g.get(k), w[k]) for k in w if not same(g.get(k, ""), w[k])}
        if diff:
            return f"metrics.csv row {i + 1} differs: {diff}"
    return None
