"""Launching and reading back the lab's sweeps: the command line every ``experiments/`` report script shares
(``--run [overrides]`` starts its ``train.py -m +experiment=...`` sweep), the jobs a sweep's ``multirun.yaml``
expected, those that left no run directory, and the command that reruns one. Reading one run directory is
:mod:`cmdp_rl.report.sweeps`, in the library."""

from __future__ import annotations

import argparse
import itertools
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from cmdp_rl.config.saved import EVAL, METRICS
from cmdp_rl.report.sweeps import RunRecord, _read_yaml, find_runs, load_run, mark_superseded

MULTIRUN_FILE = "multirun.yaml"


def _runs_holding(sweep_dir: str | Path, name: str) -> list[RunRecord]:
    return [load_run(p.parent) for p in sorted(Path(sweep_dir).glob(f"*/{name}"))]


def finished_runs(sweep_dir: str | Path) -> list[RunRecord]:
    """The sweep's run directories (one level down) that hold a result (``eval.json``)."""
    return _runs_holding(sweep_dir, EVAL)


def started_runs(sweep_dir: str | Path) -> list[RunRecord]:
    """The sweep's run directories (one level down) whose training started (``metrics.csv``)."""
    return _runs_holding(sweep_dir, METRICS)


def _expand(overrides: list[str]) -> list[list[str]]:
    """The jobs a list of overrides sweeps over: the Cartesian product of every comma-list, as
    Hydra's basic sweeper builds it (a later override of the same key replaces an earlier one)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    per_key: dict[str, list[str]] = {}
    for ov in OverridesParser.create().parse_overrides(overrides):
        key = ov.get_key_element()
        if ov.is_sweep_override():
            per_key[key] = [f"{key}={v}" for v in ov.sweep_string_iterator()]
        else:
            per_key[key] = [f"{key}={ov.get_value_element_as_str()}"]
    return [list(job) for job in itertools.product(*per_key.values())]


def expected_jobs(sweep_dir: str | Path) -> list[list[str]] | None:
    """The jobs a sweep was started with, from its ``multirun.yaml`` (None if there is none)."""
    cfg = _read_yaml(Path(sweep_dir) / MULTIRUN_FILE)
    if not isinstance(cfg, dict):
        return None
    hydra_cfg = cfg.get("hydra", {}) or {}
    params = (hydra_cfg.get("sweeper", {}) or {}).get("params", {}) or {}
    task = (hydra_cfg.get("overrides", {}) or {}).get("task", []) or []
    return _expand([f"{k}={v}" for k, v in params.items()] + [str(t) for t in task])


def missing_jobs(sweep_dir: str | Path, runs: list[RunRecord]) -> list[list[str]]:
    """Jobs listed by the sweep's ``multirun.yaml`` that left no run directory."""
    jobs = expected_jobs(sweep_dir) or []
    seen = {frozenset(r.overrides) for r in runs}
    return [job for job in jobs if frozenset(job) not in seen]


def job_values(overrides: list[str]) -> dict[str, Any]:
    """A job's overrides as ``{key: value}``, each value read as YAML (``env.start=[0.0,1.0]`` is
    a list); ``+``/``~`` prefixes dropped. For jobs that left no config to read."""
    values: dict[str, Any] = {}
    for ov in overrides:
        key, _, value = ov.lstrip("+~").partition("=")
        try:
            values[key] = yaml.safe_load(value)
        except yaml.YAMLError:
            values[key] = value
    return values


@dataclass(frozen=True)
class MissingJob:
    """A job a sweep's ``multirun.yaml`` expected that left no run directory."""

    sweep_dir: Path
    overrides: list[str]


def read_sweeps(dirs: list[Path]) -> tuple[list[RunRecord], list[MissingJob]]:
    """Every run directory under ``dirs`` (reruns marked: the superseded runs keep their status
    ``superseded``) and every job that some ``multirun.yaml`` under them expected but that left
    nothing, in directory order."""
    records: list[RunRecord] = []
    missing: list[MissingJob] = []
    for d in dirs:
        found = find_runs(d)
        records += found
        for multirun in sorted(Path(d).rglob(MULTIRUN_FILE)):
            sweep_dir = multirun.parent
            inside = [r for r in found if sweep_dir in r.path.parents]
            missing += [MissingJob(sweep_dir, job) for job in missing_jobs(sweep_dir, inside)]
    mark_superseded(records)  # a rerun of a failed or interrupted job replaces it
    return records, missing


def sweep_dir_of(run_dir: Path) -> Path:
    """The sweep a run directory belongs to: the nearest ancestor holding multirun.yaml."""
    for parent in run_dir.parents:
        if (parent / MULTIRUN_FILE).is_file():
            return parent
    return run_dir.parent


def rerun_command(overrides: list[str], sweep_dir: Path, script: str = "train.py") -> str:
    """A command that runs one job again, into ``<sweep_dir>/rerun`` (never into the sweep
    directory itself: that would replace its multirun.yaml, the record of what was expected)."""
    args = " ".join(shlex.quote(o) for o in overrides)
    return f"python {script} -m {args} hydra.sweep.dir={shlex.quote(str(sweep_dir / 'rerun'))}"


def experiment_arg_parser(doc: str | None) -> argparse.ArgumentParser:
    """The command line every ``experiments/`` report script shares: ``--run [overrides]`` runs its
    sweep first, else one sweep directory is read. Scripts add their own options to it."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="store_true", help="run the sweep first (extra args: Hydra overrides)")
    parser.add_argument("sweep_dir_or_overrides", nargs="*")
    return parser


def experiment_sweep_dir(
    parser: argparse.ArgumentParser, args: argparse.Namespace, experiment: str, root: str | Path
) -> Path:
    """The sweep directory a report reads: with ``--run``, after running
    ``train.py -m +experiment=<experiment> [overrides]`` from ``root`` (into
    ``multirun/<experiment>/<time>`` unless ``hydra.sweep.dir=`` is among the overrides). The sweep
    is a subprocess so that it is exactly what the same command typed by hand would run."""
    if not args.run:
        if len(args.sweep_dir_or_overrides) != 1:
            parser.error("give one sweep directory, or --run [overrides]")
        return Path(args.sweep_dir_or_overrides[0])
    overrides = list(args.sweep_dir_or_overrides)
    given = [o.split("=", 1)[1] for o in overrides if o.startswith("hydra.sweep.dir=")]
    if given:
        sweep_dir = Path(given[-1])
    else:
        sweep_dir = Path(root) / "multirun" / experiment / time.strftime("%Y-%m-%d_%H-%M-%S")
        overrides.append(f"hydra.sweep.dir={sweep_dir}")
    cmd = [sys.executable, str(Path(root) / "train.py"), "-m", f"+experiment={experiment}", *overrides]
    print(" ".join(cmd), flush=True)
    subprocess.run(cmd, cwd=root, check=True)
    return sweep_dir
