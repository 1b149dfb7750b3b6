"""Runs of a penalty-versus-constraint study, grouped and tabulated.

Each run is either a fixed penalty (the objective r - λc with a hand-set λ; ppo is λ = 0) or a
constrained algorithm with a budget d, from some start distribution. Runs of one (algorithm, λ or
d, start) are one group; the table gives each group's seed statistics and compares them with a
:class:`Reference`, the exact answer of the env the study ran on (for Reach1D:
``lab.studies.reach1d_reference``). Every job a sweep expected is listed with its status
(``cmdp_rl.report.sweeps``), so that a report says what is missing rather than silently averaging less.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Sequence

import numpy as np

from cmdp_rl.report.sweeps import MISSING, OK, SUPERSEDED, RunRecord
from lab.studies.stats import sample_mean_std, tail_mean
from lab.studies.tables import markdown_table, pm
from lab.sweeps import MissingJob, job_values, read_sweeps, rerun_command, sweep_dir_of

PENALTY_ALGOS = ("penalty", "ppo")  # a fixed lambda (ppo: lambda = 0)
TAIL = 0.25  # training cost: mean over the last quarter of iterations (the average iterate)
PENALTY_TOL = 0.25  # |mean cost - predicted| within this: the runs agree with the reference
BUDGET_TOL = 0.05  # mean eval cost <= d + this: the budget is met


class Reference(Protocol):
    """What the env's exact analysis predicts, per start distribution (by its label)."""

    starts: dict[str, Any]  # label -> the env's start value

    def predicted_cost(self, start_lbl: str, penalty: float) -> float:
        """Expected episode cost of the penalty-optimal policy for the fixed penalty λ."""

    def cost_curve(self, start_lbl: str, penalties: np.ndarray) -> np.ndarray:
        """``predicted_cost`` over an array of penalties."""

    def unconstrained_cost(self, start_lbl: str) -> float:
        """Expected cost of the reward-optimal policy (λ = 0): the most a budget can bind."""

    def penalty_marker(self) -> tuple[float, str] | None:
        """A penalty worth marking on the figure (a threshold) and its label, if any."""


@dataclass(frozen=True)
class GroupKey:
    algo: str
    knob: str  # "lambda" (fixed penalty) or "d" (budget of a constrained algorithm)
    value: float
    start: str

    def sort_key(self) -> tuple:
        return (self.knob != "lambda", self.algo, self.start, self.value)


@dataclass
class Run:
    key: GroupKey | None
    status: str
    path: str
    overrides: list[str]
    error: str | None = None
    seed: Any = None
    eval_return: float = math.nan
    eval_cost: float = math.nan
    train_cost: float = math.nan
    train_return: float = math.nan
    final_lambda: float = math.nan

    def sweep_dir(self) -> Path:
        """The sweep this run (or missing job) belongs to, where a rerun goes."""
        return Path(self.path) if self.status == MISSING else sweep_dir_of(Path(self.path))


def start_label(start: Any) -> str:
    if isinstance(start, (list, tuple)) and len(start) == 2:
        if float(start[0]) == float(start[1]):
            return f"x0={float(start[0]):g}"
        return f"x0~U[{float(start[0]):g},{float(start[1]):g}]"
    return f"x0={float(start):g}" if start is not None else "x0=?"


def group_key(algo: Any, penalty: Any, cost_limit: Any, start: Any) -> GroupKey | None:
    if not isinstance(algo, str):
        return None
    try:
        if algo in PENALTY_ALGOS:
            return GroupKey(algo, "lambda", float(penalty if algo == "penalty" else 0.0), start_label(start))
        return GroupKey(algo, "d", float(cost_limit), start_label(start))
    except (TypeError, ValueError):
        return None


def from_record(rec: RunRecord) -> Run:
    key = group_key(rec.get("algo.name"), rec.get("algo.penalty"), rec.get("algo.cost_limit"), rec.get("env.start"))
    run = Run(key, rec.status, str(rec.path), rec.overrides, rec.error, rec.get("seed"))
    if rec.eval is not None:
        run.eval_return = float(rec.eval.get("episode_return", math.nan))
        run.eval_cost = float(rec.eval.get("episode_cost", math.nan))
    if rec.metrics:
        run.train_cost = tail_mean([r.get("episode_cost", math.nan) for r in rec.metrics], TAIL)
        run.train_return = tail_mean([r.get("episode_return", math.nan) for r in rec.metrics], TAIL)
        run.final_lambda = rec.metrics[-1].get("lagrange_multiplier", math.nan)
    return run


def from_missing(job: MissingJob) -> Run:
    """A job that left no directory; its group is read off its overrides where it can be."""
    values = job_values(job.overrides)
    algo = values.get("algo")
    algo = algo.rsplit("/", 1)[-1] if isinstance(algo, str) else algo  # sweep/ppo_lag -> ppo_lag
    key = group_key(algo, values.get("algo.penalty"), values.get("algo.cost_limit"), values.get("env.start"))
    return Run(key, MISSING, str(job.sweep_dir), job.overrides, "no run directory", values.get("seed"))


def gather(dirs: list[Path]) -> tuple[list[Run], list[RunRecord]]:
    """Every run and missing job under the sweep directories ``dirs``, and the run records."""
    records, missing = read_sweeps(dirs)
    return [from_record(r) for r in records] + [from_missing(m) for m in missing], records


def table_rows(runs: list[Run], reference: Reference | None) -> list[dict[str, Any]]:
    """One row per group: seed statistics of its finished runs and the reference's prediction."""
    groups: dict[GroupKey, list[Run]] = defaultdict(list)
    for run in runs:
        if run.key is not None and run.status != SUPERSEDED:
            groups[run.key].append(run)
    rows = []
    for key in sorted(groups, key=GroupKey.sort_key):
        members = groups[key]
        ok = [r for r in members if r.status == OK]
        ret_m, ret_s = sample_mean_std([r.eval_return for r in ok])
        cost_m, cost_s = sample_mean_std([r.eval_cost for r in ok])
        tc_m, tc_s = sample_mean_std([r.train_cost for r in ok])
        lam_m, _ = sample_mean_std([r.final_lambda for r in ok])
        row: dict[str, Any] = {
            "algo": key.algo,
            "knob": key.knob,
            "value": key.value,
            "start": key.start,
            "runs_ok": len(ok),
            "runs": len(members),
            "return_mean": ret_m,
            "return_std": ret_s,
            "cost_mean": cost_m,
            "cost_std": cost_s,
            "train_cost_mean": tc_m,
            "train_cost_std": tc_s,
            "final_lambda_mean": lam_m,
            "predicted_cost": math.nan,
            "check": "",
        }
        if reference is not None and key.start in reference.starts and ok:
            if key.knob == "lambda":
                row["predicted_cost"] = reference.predicted_cost(key.start, key.value)
                agree = abs(cost_m - row["predicted_cost"]) <= PENALTY_TOL
                row["check"] = "agrees" if agree else "differs"
            else:
                row["predicted_cost"] = min(key.value, reference.unconstrained_cost(key.start))
                row["check"] = "meets d" if cost_m <= key.value + BUDGET_TOL else "exceeds d"
        rows.append(row)
    return rows


def _number(value: float, spec: str = ".2f") -> str:
    return f"{value:{spec}}" if math.isfinite(value) else "n/a"


def table_markdown(rows: list[dict[str, Any]]) -> str:
    header = [
        "algo",
        "λ or d",
        "start",
        "runs ok",
        "eval return",
        "eval cost",
        "train cost (last 25%)",
        "final λ",
        "predicted cost",
        "check",
    ]
    cells = [
        [
            r["algo"],
            f"λ={r['value']:g}" if r["knob"] == "lambda" else f"d={r['value']:g}",
            r["start"],
            f"{r['runs_ok']}/{r['runs']}",
            pm(r["return_mean"], r["return_std"]),
            pm(r["cost_mean"], r["cost_std"]),
            pm(r["train_cost_mean"], r["train_cost_std"]),
            _number(r["final_lambda_mean"]),
            _number(r["predicted_cost"]),
            r["check"],
        ]
        for r in rows
    ]
    return markdown_table(header, cells, align="lrlrrrrrrl") + "\n"


def penalty_markdown(rows: list[dict[str, Any]]) -> list[str]:
    """The fixed-penalty rows against the reference's prediction (lines; none without such rows)."""
    pen = [r for r in rows if r["knob"] == "lambda" and r["runs_ok"]]
    if not pen:
        return []
    cells = [
        [r["start"], f"{r['value']:g}", f"{r['predicted_cost']:.2f}", pm(r["cost_mean"], r["cost_std"]), r["check"]]
        for r in pen
    ]
    return [
        "Against the runs (mean eval cost over seeds; predicted: the penalty-optimal plan):\n",
        markdown_table(["start", "λ", "predicted cost", "runs: eval cost", "check"], cells, "lrrrl"),
        "",
    ]


def budget_markdown(rows: list[dict[str, Any]]) -> list[str]:
    """The constrained rows against the ideal cost (lines; none without such rows)."""
    con = [r for r in rows if r["knob"] == "d" and r["runs_ok"]]
    if not con:
        return []
    cells = [
        [
            r["algo"],
            r["start"],
            f"{r['value']:g}",
            f"{r['predicted_cost']:.2f}",
            pm(r["cost_mean"], r["cost_std"]),
            pm(r["train_cost_mean"], r["train_cost_std"]),
            _number(r["final_lambda_mean"]),
            r["check"],
        ]
        for r in con
    ]
    header = ["algo", "start", "d", "ideal cost", "eval cost", "train cost (last 25%)", "final λ", "check"]
    return [
        "\nConstrained runs (ideal cost = min(d, expected crossings of the unconstrained optimum)):\n",
        markdown_table(header, cells, "llrrrrrl"),
    ]


def status_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """Every run and missing job with its status, the unfinished ones first."""
    return [
        {
            "status": r.status,
            "algo": r.key.algo if r.key else "",
            "knob": r.key.knob if r.key else "",
            "value": r.key.value if r.key else "",
            "start": r.key.start if r.key else "",
            "seed": r.seed,
            "eval_return": r.eval_return,
            "eval_cost": r.eval_cost,
            "train_cost": r.train_cost,
            "final_lambda": r.final_lambda,
            "error": r.error or "",
            "path": r.path,
            "overrides": " ".join(r.overrides),
        }
        for r in sorted(runs, key=lambda r: (r.status == OK, r.path, r.overrides))
    ]


def unfinished(runs: Sequence[Run]) -> list[Run]:
    """Runs and jobs that did not finish and were not replaced by a rerun."""
    return [r for r in runs if r.status not in (OK, SUPERSEDED)]


def rerun_script(runs: Sequence[Run]) -> str:
    """A shell script running every unfinished job again, each into ``<its sweep>/rerun``."""
    redo = [r for r in unfinished(runs) if r.overrides]
    return (
        "# Runs that did not finish, each run again into <its sweep>/rerun;\n"
        "# the report then uses the rerun in place of the original.\n"
        + "".join(rerun_command(r.overrides, r.sweep_dir()) + "\n" for r in redo)
    )
