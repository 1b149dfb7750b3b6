"""Compare runs across seeds: ``python -m cmdp_rl.report.compare RUN_OR_SWEEP_DIRS... [--by algo.name]
[--csv out.csv] [--figure curves.png] [--resamples N] [--seed S]``.

Finished runs (an ``eval.json``) under the given directories are grouped by config: by the fields
named with ``--by``, else by every field but the seed (and bookkeeping such as ``total_steps``,
``threads``, ``logger``). Per group, over its runs' final evaluations, the table gives for return,
cost and the violation rate (fraction of evaluation episodes with cost above the budget) the mean and
the interquartile mean (IQM), each with rliable's 95% stratified-bootstrap interval over runs (Agarwal
et al. 2021), and a verdict against the budget d from the mean cost's interval. ``--figure`` draws each
group's learning curves with their 95% bootstrap bands. See docs/evaluation.md."""

from __future__ import annotations

import argparse
import csv
import json
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from cmdp_rl.config.run_config import flatten_dict
from cmdp_rl.report.plot import IGNORED, PANELS, Curve, config_key, draw, smooth, varying
from cmdp_rl.report.sweeps import OK, RunRecord, find_runs, mark_superseded

# (eval.json key, table name, number format)
METRICS = (
    ("episode_return", "return", ".3f"),
    ("episode_cost", "cost", ".3f"),
    ("violation_rate", "violation rate", ".1%"),
)
WITHIN = "within budget with 95% confidence"
VIOLATES = "violates the budget with 95% confidence"
INCONCLUSIVE = "inconclusive"
LEVEL = 0.95
RESAMPLES = 2000  # rliable calls the statistic once per resample in Python; a paper: 50000, its default
CURVE_POINTS = 100  # learning curves are bootstrapped at most at this many iterations


def verdict(low: float | None, high: float | None, cost_limit: float | None) -> str:
    """The claim a cost interval ``[low, high]`` supports against the budget ``cost_limit``."""
    if cost_limit is None:
        return "no verdict: the runs have different budgets"
    if low is None or high is None:
        return "no verdict: one run gives no interval"
    if high <= cost_limit:
        return WITHIN
    if low > cost_limit:
        return VIOLATES
    return INCONCLUSIVE


@dataclass
class Group:
    """Runs with the same config but for the seed (or ``--by`` values); ``stats`` per :func:`interval_estimates`."""

    label: str
    runs: list[RunRecord]
    cost_limit: float | None = None
    stats: dict[str, dict[str, Any]] = field(default_factory=dict)
    verdict: str = ""


def _quietly(fn: Callable[[], Any]) -> Any:
    """Quiet arch's warning about rliable's ``random_state`` and numpy's about an all-NaN iteration."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        warnings.simplefilter("ignore", RuntimeWarning)
        return fn()


def _bootstrap(
    scores: dict[str, np.ndarray], func: Callable[[np.ndarray], np.ndarray], resamples: int, seed: int
) -> dict[str, np.ndarray]:
    """rliable's stratified-bootstrap intervals, reproducible: rliable 1.2 draws from numpy's global
    generator, not the ``random_state`` it is given, so that one is seeded for the call and put back."""
    from rliable import library as rly

    state = np.random.get_state()
    np.random.seed(seed)
    try:
        _, ci = _quietly(
            lambda: rly.get_interval_estimates(
                scores, func, reps=resamples, confidence_interval_size=LEVEL, random_state=np.random.RandomState(seed)
            )
        )
    finally:
        np.random.set_state(state)
    return ci


def interval_estimates(scores: np.ndarray, resamples: int = RESAMPLES, seed: int = 0) -> dict[str, Any]:
    """``n``, mean and IQM of one score per run, with 95% stratified-bootstrap intervals (rliable):
    ``mean_low``, ``mean_high``, ``iqm_low``, ``iqm_high``, None with fewer than 2 runs."""
    from rliable import metrics

    x = np.asarray(scores, dtype=np.float64)
    x = x[np.isfinite(x)].reshape(-1, 1)  # (runs, tasks = 1), rliable's layout
    out: dict[str, Any] = dict.fromkeys(("mean", "mean_low", "mean_high", "iqm", "iqm_low", "iqm_high"))
    if len(x):
        out.update(mean=float(metrics.aggregate_mean(x)), iqm=float(metrics.aggregate_iqm(x)))
    if len(x) > 1:
        agg = lambda s: np.array([metrics.aggregate_mean(s), metrics.aggregate_iqm(s)])  # noqa: E731
        (mean_low, iqm_low), (mean_high, iqm_high) = _bootstrap({"g": x}, agg, resamples, seed)["g"]
        out.update(
            mean_low=float(mean_low), mean_high=float(mean_high), iqm_low=float(iqm_low), iqm_high=float(iqm_high)
        )
    return {"n": len(x), **out}


def load_runs(paths: Sequence[str | Path]) -> tuple[list[RunRecord], list[RunRecord]]:
    """``(finished, not finished)`` runs under ``paths``; a rerun supersedes the run it repeats."""
    records: dict[Path, RunRecord] = {}
    for p in paths:
        if not Path(p).is_dir():
            raise FileNotFoundError(f"compare: {p} is not a directory")
        found = find_runs(p)
        if not found:
            raise FileNotFoundError(f"compare: no run directory under {p}")
        for r in found:
            records.setdefault(r.path.resolve(), r)
    runs = list(records.values())
    mark_superseded(runs)
    return [r for r in runs if r.status == OK], [r for r in runs if r.status != OK]


def _value(v: Any) -> str:
    return json.dumps(v, default=str) if not isinstance(v, str) else v


def group_runs(runs: Sequence[RunRecord], by: Sequence[str] = ()) -> list[Group]:
    """Group by the ``by`` fields' values, else by the whole config but :data:`IGNORED`."""
    flat = [flatten_dict(r.config) for r in runs]
    if by:
        keys = [tuple(_value(f.get(b, "?")) for b in by) for f in flat]
        labels = {k: ", ".join(f"{b}={v}" for b, v in zip(by, k)) for k in keys}
    else:
        keys = [config_key(f, IGNORED.__contains__) for f in flat]
        firsts = {k: f for k, f in zip(keys, flat)}
        names = varying(list(firsts.values()), IGNORED.__contains__)
        labels = {k: ", ".join(f"{v}={_value(f[v])}" for v in names) or "all runs" for k, f in firsts.items()}
    groups: dict[Any, Group] = {}
    for key, run in zip(keys, runs):
        groups.setdefault(key, Group(labels[key], [])).runs.append(run)
    return sorted(groups.values(), key=lambda g: g.label)


def _budget(run: RunRecord) -> float | None:
    d = (run.eval or {}).get("cost_limit", run.get("algo.cost_limit"))
    return None if d is None else float(d)


def compare(
    paths: Sequence[str | Path], by: Sequence[str] = (), resamples: int = RESAMPLES, seed: int = 0
) -> tuple[list[Group], list[RunRecord]]:
    """Groups of the finished runs under ``paths`` with their figures and verdicts, and the unfinished runs."""
    done, unfinished = load_runs(paths)
    groups = group_runs(done, by)
    for g in groups:
        budgets = {_budget(r) for r in g.runs}
        g.cost_limit = budgets.pop() if len(budgets) == 1 else None
        for name, _, _ in METRICS:
            values = [(r.eval or {}).get(name) for r in g.runs]  # an older eval.json may lack one
            scores = np.array([np.nan if v is None else float(v) for v in values])
            g.stats[name] = interval_estimates(scores, resamples, seed)
        cost = g.stats["episode_cost"]
        g.verdict = verdict(cost["mean_low"], cost["mean_high"], g.cost_limit)
    return groups, unfinished


def _fmt(v: float | None, fmt: str) -> str:
    return "n/a" if v is None else format(v, fmt)


def _cell(s: dict[str, Any], p: str, fmt: str) -> str:
    """``p`` (mean or iqm) of the stats ``s`` with its interval."""
    return f"{_fmt(s[p], fmt)} [{_fmt(s[p + '_low'], fmt)}, {_fmt(s[p + '_high'], fmt)}]" if s["n"] else "n/a"


def format_table(groups: Sequence[Group]) -> str:
    """The comparison as aligned text, a block of rows per group."""
    head = ("group", "runs", "metric", "mean [95% CI]", "IQM [95% CI]")
    rows = []
    for g in groups:
        for i, (name, title, fmt) in enumerate(METRICS):
            s = g.stats[name]
            rows.append((g.label if i == 0 else "", str(s["n"]), title, _cell(s, "mean", fmt), _cell(s, "iqm", fmt)))
        budget = "n/a (budgets differ)" if g.cost_limit is None else f"{g.cost_limit:g}"
        rows.append(("", "", "budget d", budget, g.verdict))
    widths = [max(len(r[j]) for r in [head, *rows]) for j in range(len(head))]
    line = lambda r: "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip()  # noqa: E731
    return "\n".join([line(head), line(tuple("-" * w for w in widths)), *map(line, rows)])


def write_csv(groups: Sequence[Group], path: str | Path) -> Path:
    """One row per group: runs, budget, verdict, and for each metric n, mean, IQM and their bounds."""
    rows = [
        {"group": g.label, "runs": len(g.runs), "cost_limit": g.cost_limit, "verdict": g.verdict}
        | {f"{name}_{k}": v for name, _, _ in METRICS for k, v in g.stats[name].items()}
        for g in groups
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["group"])
        writer.writeheader()
        writer.writerows(rows)
    return path


def curve_band(
    runs: Sequence[RunRecord], name: str, k: int = 5, resamples: int = RESAMPLES, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(step, mean, low, high)`` of metric ``name`` over ``runs``' metrics.csv, each smoothed over ``k``
    iterations, cut to those every run reached and thinned to :data:`CURVE_POINTS`; the band: rliable's."""
    n = min(len(r.metrics) for r in runs)
    idx = np.unique(np.linspace(0, n - 1, min(n, CURVE_POINTS)).round().astype(int)) if n else np.array([], int)
    step = np.array([runs[0].metrics[i]["step"] for i in idx])
    x = np.stack([smooth(np.array([row.get(name, np.nan) for row in r.metrics[:n]]), k)[idx] for r in runs])
    mean = _quietly(lambda: np.nanmean(x, axis=0))
    if len(runs) < 2 or n == 0:
        return step, mean, mean, mean
    ci = _bootstrap({"g": x[:, None, :]}, lambda s: np.nanmean(s[:, 0, :], axis=0), min(resamples, RESAMPLES), seed)
    return step, mean, ci["g"][0], ci["g"][1]


def plot_groups(
    groups: Sequence[Group], out: str | Path, k: int = 5, resamples: int = RESAMPLES, seed: int = 0
) -> Path:
    """Learning curves of each group's return and cost with their 95% bands into the PNG ``out``."""
    curves = []
    for g in groups:
        runs = [r for r in g.runs if r.metrics]
        if runs:
            bands = {name: curve_band(runs, name, k, resamples, seed) for name, _ in PANELS[:2]}
            mean, band = {n: b[1] for n, b in bands.items()}, {n: b[2:] for n, b in bands.items()}
            limits = {} if g.cost_limit is None else {"episode_cost": g.cost_limit}
            label = f"{g.label} ({len(runs)} runs)"
            curves.append(Curve(label, bands["episode_cost"][0], mean, band, len(runs), limits, list(PANELS[:2])))
    return draw(curves, out, f"mean over runs, 95% stratified-bootstrap band; trailing mean over {k} iterations")


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The command's arguments (``argv``; default: the process's); a bad one exits with status 2."""
    parser = argparse.ArgumentParser(
        prog="python -m cmdp_rl.report.compare",
        description=__doc__.split("\n\n")[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("paths", nargs="+", help="run directories or sweep directories (searched for runs)")
    parser.add_argument(
        "--by", action="append", default=[], help="config fields to group by (dotted; repeat or comma-separate)"
    )
    parser.add_argument("--csv", help="also write the table as CSV, one row per group")
    parser.add_argument("--figure", help="write learning curves with 95%% bands to this PNG")
    parser.add_argument("--resamples", type=int, default=RESAMPLES, help=f"bootstrap resamples (default {RESAMPLES})")
    parser.add_argument("--seed", type=int, default=0, help="the bootstrap's seed (default 0)")
    parser.add_argument("--smooth", type=int, default=5, help="curves: trailing mean over this many iterations")
    args = parser.parse_args(argv)
    if args.resamples < 100:
        parser.error(f"--resamples must be at least 100, got {args.resamples}")
    if args.smooth < 1:
        parser.error(f"--smooth must be a positive integer, got {args.smooth}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    by = [b.strip() for item in args.by for b in item.split(",") if b.strip()]
    try:
        groups, unfinished = compare(args.paths, by, args.resamples, args.seed)
    except FileNotFoundError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not groups:
        print("error: compare: no finished run (none has eval.json)", file=sys.stderr)
        return 2
    print(format_table(groups))
    if any(len(g.runs) < 5 for g in groups):
        print(
            "note: with fewer than 5 runs a bootstrap interval over runs cannot be wider than the runs'"
            " own range; treat its verdict as weak (docs/evaluation.md)"
        )
    for r in unfinished:
        print(f"skipped {r.path} ({r.status}{': ' + r.error if r.error else ''})")
    if args.csv:
        print(f"wrote {write_csv(groups, args.csv)}")
    if args.figure:
        print(f"wrote {plot_groups(groups, args.figure, args.smooth, args.resamples, args.seed)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
