"""A run crashed between checkpoints and resumed, and the check that it ends as the uninterrupted run did."""

from pathlib import Path
from typing import Callable

import pytest
import torch

from cmdp_rl import load_config, train
from cmdp_rl.report.metrics import MetricsLogger
from cmdp_rl.run.checkpoint import load_checkpoint
from helpers.runs import eval_result, metrics_rows


class Crash(Exception):
    pass


def crash_after_row(monkeypatch, iteration: int) -> None:
    """Make training die right after writing the metrics row of ``iteration``."""
    original = MetricsLogger.log

    def log(self, row, force_echo=False, **kwargs):
        original(self, row, force_echo, **kwargs)
        if row["iteration"] == iteration:
            raise Crash

    monkeypatch.setattr(MetricsLogger, "log", log)


def crash_then_resume(
    cfg: dict, tmp_path: Path, monkeypatch, quiet, crash_after: int = 5, checked: Callable[[Path], None] | None = None
) -> tuple[Path, Path]:
    """Train ``cfg`` whole, then again dying after row ``crash_after`` and resumed from its last
    checkpoint (``checked(broken)`` runs between the crash and the resume); both run dirs."""
    whole, broken = tmp_path / "whole", tmp_path / "broken"
    train(load_config(cfg), whole, echo=quiet)
    crash_after_row(monkeypatch, crash_after)
    with pytest.raises(Crash):
        train(load_config(cfg), broken, echo=quiet)
    monkeypatch.undo()
    if checked is not None:
        checked(broken)
    train(load_config({**cfg, "resume": str(broken)}), echo=quiet)
    return whole, broken


def final_state(run_dir: Path) -> dict:
    return load_checkpoint(run_dir / "checkpoint.pt")["members"][0]["algo_state"]


def assert_same_run(a: Path, b: Path) -> None:
    ra, rb = metrics_rows(a), metrics_rows(b)
    assert [r["iteration"] for r in rb] == [str(i) for i in range(1, len(ra) + 1)]  # contiguous
    assert ra == rb  # every column but wall-clock, bit for bit
    assert eval_result(a) == eval_result(b)
    sa, sb = final_state(a), final_state(b)
    for k, t in sa["networks"].items():
        assert torch.equal(t, sb["networks"][k]), k
    assert sa.get("multiplier") == sb.get("multiplier")
