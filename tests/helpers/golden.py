"""The numbers recorded in ``tests/golden/`` and how a run's outputs are compared with them.

A recording is one case's ``metrics.csv`` rows and ``eval.json`` with ``recorded``: where those
numbers were written or reproduced bit for bit (the CPU, torch's kernel level, numpy's SIMD targets,
OpenBLAS's core, MKL's branch: helpers/kernels.py) and when. A case passes if its outputs equal,
exactly, any recording of it (``<case>.json``, then ``machines/<cpu>/<case>.json``). Otherwise a
recording made with this CPU and these kernels is the same path on the same machine: the case fails.
Otherwise it must agree with the first recording within :data:`CROSS_CPU`.
"""

import datetime
import json
import os
import re
import subprocess
from pathlib import Path

import pytest
import torch

from helpers.kernels import dispatch
from helpers.runs import ROOT, eval_result, metrics_rows
from helpers.tolerance import Tolerance, record, share

GOLDEN = Path(__file__).resolve().parents[1] / "golden"
WRITE = os.environ.get("CMDP_RL_WRITE_GOLDEN") == "1"
# Measured on 2026-12-07 (docs/testing.md, "Golden numbers on another CPU"): each golden case under
# make test-cpus' three settings and alone under each variable, against its first recording, and
# this AMD EPYC against the Intel Xeon's recordings. Seven iterations of training carry the last-bit
# differences of other kernels to at most 3.3e-4 relative on numbers above 1e-6 (pcpo's
# surr_reward_change, -0.0073, under the sse4 setting) and 1.1e-3 relative on a number near zero
# (cpo_lstm's episode_return_min, -0.0012, 1.3e-6 apart on the Intel). The worst of them uses a third of
# rel 1e-3 / abs 5e-6: a 3x margin. A change of algorithm moves these numbers by percents.
CROSS_CPU = Tolerance("golden numbers on another CPU", rel=1e-3, abs=5e-6)


def outputs(run_dir: Path) -> dict:
    res = eval_result(run_dir)
    res.pop("torch_threads", None)
    return {"metrics": metrics_rows(run_dir), "eval": res}


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines() if Path("/proc/cpuinfo").exists() else []:
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown-cpu"


def machine() -> str:
    """The folder of this machine's recordings: its CPU model and torch's kernel level."""
    return re.sub(r"[^A-Za-z0-9]+", "-", cpu_model()).strip("-") + "_" + torch.backends.cpu.get_cpu_capability()


def here() -> dict:
    """Where this process computes: the CPU and the kernels its libraries picked."""
    return {"cpu": cpu_model(), **dispatch()}


def _number(v) -> float | None:
    if isinstance(v, bool) or v is None or v == "":
        return None
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def _pairs(got, want, where: str, missing):
    """``(where, got, recorded)`` for each value a recording holds (a list's length is a value too)."""
    if isinstance(want, dict):
        got = got if isinstance(got, dict) else {}
        for k, w in want.items():
            yield from _pairs(got.get(k, missing), w, f"{where}.{k}", missing)
    elif isinstance(want, list):
        if not isinstance(got, list) or len(got) != len(want):
            yield f"{where} (length)", got if not isinstance(got, list) else len(got), len(want)
        else:
            for i, (g, w) in enumerate(zip(got, want)):
                yield from _pairs(g, w, f"{where}[{i}]", missing)
    else:
        yield where, got, want


def compared(got: dict, want: dict):
    """Every value of a recording beside this run's. metrics.csv's columns that another algorithm fills
    were blank in older recordings; each algorithm now writes only the statistics it declares, so a
    column may be absent (read as blank): every recorded number must still be there."""
    yield from _pairs(got["eval"], want["eval"], "eval.json", None)
    yield from _pairs(got["metrics"], want["metrics"], "metrics.csv", "")


def difference(got: dict, want: dict) -> str | None:
    """The first value that differs in any bit (``None``: none does)."""
    return next((f"{w}: {g!r} != {r!r}" for w, g, r in compared(got, want) if g != r), None)


def largest_share(got: dict, want: dict) -> tuple[float, str]:
    """The largest share of :data:`CROSS_CPU` a number uses, and where (inf: a value that is not a number differs)."""
    worst, at = 0.0, ""
    for w, g, r in compared(got, want):
        if g == r:
            continue
        x, y = _number(g), _number(r)
        used = share(x, y, CROSS_CPU) if x is not None and y is not None else float("inf")
        if used > worst:
            worst, at = used, f"{w}: {g!r} against {r!r}"
    return worst, at


def write(name: str, got: dict) -> Path:
    """Record ``got`` as the first recording, or as this machine's if there is one."""
    first = GOLDEN / f"{name}.json"
    path = first if not first.exists() else GOLDEN / "machines" / machine() / f"{name}.json"
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    when = {"date": datetime.date.today().isoformat(), "commit": commit.stdout.strip() or "unknown"}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**got, "recorded": [{**when, **here()}]}, indent=1, sort_keys=True))
    return path


def check(name: str, got: dict) -> None:
    """Pass, fail or (with ``CMDP_RL_WRITE_GOLDEN=1``) record, as the module's docstring says."""
    if WRITE:
        pytest.skip(f"wrote {write(name, got)}")
    paths = [GOLDEN / f"{name}.json", *sorted(GOLDEN.glob(f"machines/*/{name}.json"))]
    recordings = {p: json.loads(p.read_text()) for p in paths}
    exact = {p: difference(got, r) for p, r in recordings.items()}
    if None in exact.values():
        return
    now = here()
    ours = [p for p, r in recordings.items() if any(all(w.get(k) == v for k, v in now.items()) for w in r["recorded"])]
    assert not ours, (
        f"{name}: differs from {ours[0].relative_to(GOLDEN)}, recorded with these kernels: {exact[ours[0]]}"
    )
    used, at = largest_share(got, next(iter(recordings.values())))
    record(CROSS_CPU, used)
    assert used <= 1.0, f"{name}: beyond {CROSS_CPU} of its first recording ({used:.3g} of it) at {at}"
