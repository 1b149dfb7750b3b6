"""Reading run directories back (what they hold: ``config/saved.py``): an aggregator reads results from here instead
of re-training, and reports every run that did not finish (failed, interrupted, or never started) rather than crash
on it."""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from cmdp_rl.config.saved import CONFIG as CONFIG_FILE
from cmdp_rl.config.saved import ERROR as ERROR_FILE
from cmdp_rl.config.saved import EVAL as EVAL_FILE
from cmdp_rl.config.saved import HYDRA_DIR, POPULATION_CONFIG, deploy_node
from cmdp_rl.config.saved import METRICS as METRICS_FILE
from cmdp_rl.report.metrics import read_metrics

OK, FAILED, INCOMPLETE, MISSING = "ok", "failed", "incomplete", "missing"
SUPERSEDED = "superseded"  # the same job ran again (a rerun) and that run is the one kept


@dataclass
class RunRecord:
    """One run directory, read back. ``status`` is ``ok`` (eval.json), ``failed`` (error.txt or an
    unreadable eval.json) or ``incomplete`` (started, no result: killed, crashed hard, or running)."""

    path: Path
    status: str
    overrides: list[str]
    config: dict[str, Any]
    eval: dict[str, Any] | None = None
    metrics: list[dict[str, float]] = field(default_factory=list)
    error: str | None = None

    def get(self, dotted: str, default: Any = None) -> Any:
        """A config value by dotted key, e.g. ``run.get("algo.penalty")``."""
        node: Any = self.config
        for part in dotted.split("."):
            if not isinstance(node, dict) or part not in node:
                return default
            node = node[part]
        return node


def _read_yaml(path: Path) -> Any:
    try:
        return yaml.safe_load(path.read_text()) if path.is_file() else None
    except (OSError, yaml.YAMLError):
        return None


def load_run(path: str | Path) -> RunRecord:
    """Read one run directory; never raises on missing or damaged files."""
    path = Path(path)
    overrides = _read_yaml(path / HYDRA_DIR / "overrides.yaml") or []
    # The validated config (written when training starts) is the truth; Hydra's composed one is
    # there from the job's start, also for runs that failed validation.
    config = _read_yaml(path / CONFIG_FILE) or _read_yaml(path / HYDRA_DIR / "config.yaml") or {}
    config = deploy_node(config)  # a run saved with the flat deployment options groups with the node's
    record = RunRecord(path, INCOMPLETE, [str(o) for o in overrides], config, metrics=read_metrics(path / METRICS_FILE))
    if (path / EVAL_FILE).is_file():
        try:
            record.eval, record.status = json.loads((path / EVAL_FILE).read_text()), OK
        except (OSError, ValueError) as exc:
            record.status, record.error = FAILED, f"{EVAL_FILE} unreadable: {exc}"
    elif (path / ERROR_FILE).is_file():
        text = (path / ERROR_FILE).read_text()
        record.status, record.error = FAILED, text.splitlines()[0] if text else "error"
    return record


def find_runs(root: str | Path) -> list[RunRecord]:
    """Every run directory under ``root`` (a directory holding ``.hydra/`` or ``config.yaml``)."""
    root = Path(root)

    def inside_hydra(p: Path) -> bool:  # .hydra/ itself, or a resume's record in .hydra/resume_*/
        return HYDRA_DIR in p.relative_to(root).parts[:-1]

    dirs = {p.parent for p in root.rglob(HYDRA_DIR) if p.is_dir() and not inside_hydra(p)}
    dirs |= {p.parent for p in root.rglob(CONFIG_FILE) if not inside_hydra(p)}
    # A population's own directory (cmdp_rl/population/) is not a run: its agents' directories are.
    return [load_run(d) for d in sorted(dirs) if not (d / POPULATION_CONFIG).is_file()]


def _finished_at(record: RunRecord) -> float:
    for name in (EVAL_FILE, ERROR_FILE, METRICS_FILE):
        if (record.path / name).is_file():
            return (record.path / name).stat().st_mtime
    return record.path.stat().st_mtime


def mark_superseded(records: list[RunRecord]) -> None:
    """Where several directories hold the same job (same overrides: a rerun of a failed or
    interrupted job), keep the newest finished one, else the newest; mark the others superseded."""
    by_job: dict[frozenset, list[RunRecord]] = defaultdict(list)
    for r in records:
        if r.overrides:
            by_job[frozenset(r.overrides)].append(r)
    for group in by_job.values():
        if len(group) > 1:
            keep = max([r for r in group if r.status == OK] or group, key=_finished_at)
            for r in group:
                if r is not keep:
                    r.status = SUPERSEDED
