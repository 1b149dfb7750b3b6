"""Penalty versus constraint on Reach1D (the seed's second exercise), from a sweep's outputs.

    python experiments/penalty_vs_constraint.py multirun/penalty_vs_constraint/<time> [...] [--out DIR]

Reads every run directory under the given sweep directories (``make sweep`` writes them; nothing
is re-trained) and writes, into ``--out`` (default ``<first dir>/report``):

- ``table.md`` / ``table.csv``: per algorithm, lambda or budget d, and start distribution: runs
  finished out of expected, mean and spread (std over seeds) of the final evaluation's episode
  return and cost, the training episode cost over the last quarter of iterations, the final lambda,
  and what the analysis predicts;
- ``runs.csv``: every run (and every job the sweeps' multirun.yaml expected but that left nothing)
  with its status: ok, failed (error.txt says why), incomplete (started, no result: killed, or
  its joblib pool was broken by another job's hard crash), missing (never started), superseded
  (the same job ran again: the rerun is used);
- ``rerun.sh``: one command per job that did not finish, running it again into
  ``<its sweep>/rerun``;
- ``penalty_vs_constraint.png``: episode cost against lambda for the penalty runs, each budget d a
  horizontal line, the penalty-optimal step function from the analysis; achieved cost against d
  for the constrained runs, the diagonal the ideal;
- ``answers.md``: the exercise's answers computed from the env's parameters
  (``cmdp_rl.envs.reach1d_dp``) and checked against the runs.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from cmdp_rl.envs.reach1d_task import Reach1DConfig
from cmdp_rl.envs.reach1d_dp import CrossingThresholds, closed_form_threshold, crossing_thresholds
from cmdp_rl.plot import pyplot, save_figure
from cmdp_rl.sweeps import (
    MISSING, MULTIRUN_FILE, OK, SUPERSEDED, RunRecord, find_runs, mark_superseded, missing_jobs, rerun_command,
    sweep_dir_of,
)

PENALTY_ALGOS = ("penalty", "ppo")  # a fixed lambda (ppo: lambda = 0)
TAIL = 0.25  # training cost: mean over the last quarter of iterations (the average iterate)
PENALTY_TOL = 0.25  # |mean cost - predicted| within this: the runs agree with the analysis
BUDGET_TOL = 0.05  # mean eval cost <= d + this: the budget is met
SHOW_NOT_OK = 20  # runs that did not finish listed on the console (all of them in runs.csv)


# --------------------------------------------------------------------------------------------
# Gathering
# --------------------------------------------------------------------------------------------
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


def start_label(start: Any) -> str:
    if isinstance(start, (list, tuple)) and len(start) == 2:
        if float(start[0]) == float(start[1]):
            return f"x0={float(start[0]):g}"
        return f"x0~U[{float(start[0]):g},{float(start[1]):g}]"
    return f"x0={float(start):g}" if start is not None else "x0=?"


def _key(algo: Any, penalty: Any, cost_limit: Any, start: Any) -> GroupKey | None:
    if not isinstance(algo, str):
        return None
    try:
        if algo in PENALTY_ALGOS:
            return GroupKey(algo, "lambda", float(penalty if algo == "penalty" else 0.0), start_label(start))
        return GroupKey(algo, "d", float(cost_limit), start_label(start))
    except (TypeError, ValueError):
        return None


def _tail_mean(rows: list[dict[str, float]], column: str) -> float:
    values = [r.get(column, math.nan) for r in rows]
    if not values:
        return math.nan
    tail = np.array(values[-max(1, int(round(len(values) * TAIL))):], dtype=float)
    tail = tail[np.isfinite(tail)]
    return float(tail.mean()) if tail.size else math.nan


def from_record(rec: RunRecord) -> Run:
    key = _key(rec.get("algo.name"), rec.get("algo.penalty"), rec.get("algo.cost_limit"), rec.get("env.start"))
    run = Run(key, rec.status, str(rec.path), rec.overrides, rec.error, rec.get("seed"))
    if rec.eval is not None:
        run.eval_return = float(rec.eval.get("episode_return", math.nan))
        run.eval_cost = float(rec.eval.get("episode_cost", math.nan))
    if rec.metrics:
        run.train_cost = _tail_mean(rec.metrics, "episode_cost")
        run.train_return = _tail_mean(rec.metrics, "episode_return")
        run.final_lambda = rec.metrics[-1].get("lagrange_multiplier", math.nan)
    return run


def from_missing(overrides: list[str], sweep_dir: Path) -> Run:
    """A job that left no directory; its group is read off its overrides where it can be."""
    values: dict[str, Any] = {}
    for ov in overrides:
        k, _, v = ov.lstrip("+~").partition("=")
        try:
            values[k] = yaml.safe_load(v)
        except yaml.YAMLError:
            values[k] = v
    algo = values.get("algo")
    algo = algo.rsplit("/", 1)[-1] if isinstance(algo, str) else algo  # sweep/ppo_lag -> ppo_lag
    key = _key(algo, values.get("algo.penalty"), values.get("algo.cost_limit"), values.get("env.start"))
    return Run(key, MISSING, str(sweep_dir), overrides, "no run directory", values.get("seed"))


def gather(dirs: list[Path]) -> tuple[list[Run], list[RunRecord]]:
    runs: list[Run] = []
    records: list[RunRecord] = []
    for d in dirs:
        recs = find_runs(d)
        records += recs
        for multirun in sorted(d.rglob(MULTIRUN_FILE)):
            sweep_dir = multirun.parent
            inside = [r for r in recs if sweep_dir in r.path.parents]
            runs += [from_missing(job, sweep_dir) for job in missing_jobs(sweep_dir, inside)]
    mark_superseded(records)  # a rerun of a failed or interrupted job replaces it
    runs = [from_record(r) for r in records] + runs
    return runs, records


# --------------------------------------------------------------------------------------------
# Analysis from the env's parameters
# --------------------------------------------------------------------------------------------
@dataclass
class Analysis:
    env: Reach1DConfig
    gamma: float
    cost_gamma: float
    thresholds: CrossingThresholds
    starts: dict[str, Any] = field(default_factory=dict)  # label -> env.start value
    mixed_envs: list[str] = field(default_factory=list)  # runs whose env differs beyond the start

    def predicted_cost(self, start_lbl: str, penalty: float) -> float:
        return float(self.thresholds.expected_cost(self.starts[start_lbl], penalty)[0])

    def unconstrained_cost(self, start_lbl: str) -> float:
        """Expected crossings of the reward-optimal plan (lambda = 0), the most a budget can bind."""
        return self.predicted_cost(start_lbl, 0.0)


def analyse(records: list[RunRecord]) -> Analysis | None:
    """The DP analysis for the env the runs used (the first finished run's env; a sweep over env
    parameters other than the start would need one analysis per env and is reported as such)."""
    configs = [r for r in records if isinstance(r.config.get("env"), dict)]
    if not configs:
        return None
    first = configs[0]
    env_fields = {f.name for f in dataclasses.fields(Reach1DConfig)}
    env = Reach1DConfig(**{k: v for k, v in first.config["env"].items() if k in env_fields})
    gamma = float(first.get("algo.gamma", 0.99))
    cost_gamma = float(first.get("algo.cost_gamma", gamma))
    analysis = Analysis(env, gamma, cost_gamma, crossing_thresholds(env, gamma, cost_gamma))
    for r in configs:
        start = r.config["env"].get("start")
        analysis.starts.setdefault(start_label(start), start)
        if {k: v for k, v in r.config["env"].items() if k != "start"} != {
                k: v for k, v in first.config["env"].items() if k != "start"}:
            analysis.mixed_envs.append(str(r.path))
    return analysis


# --------------------------------------------------------------------------------------------
# Table
# --------------------------------------------------------------------------------------------
def _stats(values: list[float]) -> tuple[float, float]:
    v = np.array([x for x in values if math.isfinite(x)], dtype=float)
    if v.size == 0:
        return math.nan, math.nan
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else math.nan


def table_rows(runs: list[Run], analysis: Analysis | None) -> list[dict[str, Any]]:
    groups: dict[GroupKey, list[Run]] = defaultdict(list)
    for run in runs:
        if run.key is not None and run.status != SUPERSEDED:
            groups[run.key].append(run)
    rows = []
    for key in sorted(groups, key=GroupKey.sort_key):
        members = groups[key]
        ok = [r for r in members if r.status == OK]
        ret_m, ret_s = _stats([r.eval_return for r in ok])
        cost_m, cost_s = _stats([r.eval_cost for r in ok])
        tc_m, tc_s = _stats([r.train_cost for r in ok])
        lam_m, _ = _stats([r.final_lambda for r in ok])
        row: dict[str, Any] = {
            "algo": key.algo, "knob": key.knob, "value": key.value, "start": key.start,
            "runs_ok": len(ok), "runs": len(members),
            "return_mean": ret_m, "return_std": ret_s, "cost_mean": cost_m, "cost_std": cost_s,
            "train_cost_mean": tc_m, "train_cost_std": tc_s, "final_lambda_mean": lam_m,
            "predicted_cost": math.nan, "check": "",
        }
        if analysis is not None and key.start in analysis.starts and ok:
            if key.knob == "lambda":
                row["predicted_cost"] = analysis.predicted_cost(key.start, key.value)
                agree = abs(cost_m - row["predicted_cost"]) <= PENALTY_TOL
                row["check"] = "agrees" if agree else "differs"
            else:
                row["predicted_cost"] = min(key.value, analysis.unconstrained_cost(key.start))
                row["check"] = "meets d" if cost_m <= key.value + BUDGET_TOL else "exceeds d"
        rows.append(row)
    return rows


def _pm(mean: float, std: float) -> str:
    if not math.isfinite(mean):
        return "n/a"
    return f"{mean:.3f}" + (f" ± {std:.3f}" if math.isfinite(std) else "")


def table_markdown(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| algo | λ or d | start | runs ok | eval return | eval cost | train cost (last 25%) | final λ | predicted cost | check |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        knob = f"λ={r['value']:g}" if r["knob"] == "lambda" else f"d={r['value']:g}"
        pred = f"{r['predicted_cost']:.2f}" if math.isfinite(r["predicted_cost"]) else "n/a"
        lam = f"{r['final_lambda_mean']:.2f}" if math.isfinite(r["final_lambda_mean"]) else "n/a"
        lines.append(
            f"| {r['algo']} | {knob} | {r['start']} | {r['runs_ok']}/{r['runs']} | "
            f"{_pm(r['return_mean'], r['return_std'])} | {_pm(r['cost_mean'], r['cost_std'])} | "
            f"{_pm(r['train_cost_mean'], r['train_cost_std'])} | {lam} | {pred} | {r['check']} |"
        )
    return "\n".join(lines) + "\n"


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    if not rows:
        path.write_text("")
        return
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def status_rows(runs: list[Run]) -> list[dict[str, Any]]:
    return [{
        "status": r.status, "algo": r.key.algo if r.key else "", "knob": r.key.knob if r.key else "",
        "value": r.key.value if r.key else "", "start": r.key.start if r.key else "", "seed": r.seed,
        "eval_return": r.eval_return, "eval_cost": r.eval_cost, "train_cost": r.train_cost,
        "final_lambda": r.final_lambda, "error": r.error or "", "path": r.path,
        "overrides": " ".join(r.overrides),
    } for r in sorted(runs, key=lambda r: (r.status == OK, r.path, r.overrides))]


# --------------------------------------------------------------------------------------------
# Answers
# --------------------------------------------------------------------------------------------
def answers_markdown(analysis: Analysis | None, rows: list[dict[str, Any]]) -> str:
    if analysis is None:
        return "No run has a readable config: nothing to analyse.\n"
    e, g = analysis.env, analysis.gamma
    th = analysis.thresholds
    out = ["# Penalty versus constraint: answers from the env's parameters\n"]
    out.append(
        f"Env: wall={e.wall}, wall_x={e.wall_x}, goal={e.goal}, max_steps={e.max_steps}; "
        f"gamma={g}, cost_gamma={analysis.cost_gamma}. Exact plans on the true state "
        "(no sensor noise), positions on a 0.001 grid (`cmdp_rl/envs/reach1d_dp.py`).\n"
    )
    if analysis.mixed_envs:
        out.append(f"Warning: {len(analysis.mixed_envs)} runs used other env parameters than the first "
                   f"(e.g. {analysis.mixed_envs[0]}); the analysis below is for the first run's env.\n")
    if e.wall != "pass":
        out.append("With wall=block a crossing move is cancelled: crossing never pays, for any "
                   "lambda >= 0, so there is no threshold to find.\n")
    seed_start = th.at(0.1)
    out.append("## (a) A penalty under which the optimal policy still collides\n")
    lines = [
        f"From the seed's start x0 = 0.1 the penalty-optimal policy crosses the wall for every "
        f"lambda < lambda* = {seed_start:.4f} (DP)",
    ]
    if e.wall == "pass" and analysis.cost_gamma == g:
        cf = closed_form_threshold(e, g)
        lines[0] += (
            f"; by hand, lambda* = 0.1 (1 + γ + γ² + γ³) + γ³ = {cf:.4f} for γ = {g}: walking to the "
            "wall is worth the same whether or not it then crosses, so the choice is made at the "
            "wall: cross (4 moves of 0.1 reach the goal band, 0.4 of shaped progress with the +1 "
            "bonus on the 4th, and the crossing cost 1 is paid on the first of them, undiscounted) "
            "or stop (worth 0). Undiscounted (γ → 1) lambda* = 0.4 + 1 = 1.4: the whole "
            "trajectory earns 0.8 + 1 = 1.8 − λ against 0.4 for stopping at the wall"
        )
    lines[0] += (
        ". So for example lambda = 1 leaves the optimal policy colliding once per episode: "
        "the goal bonus and the progress beyond the wall outweigh the penalty. Assumptions: the "
        "true state is known (the agent only sees it with noise sigma = 0.02, which costs a "
        "margin near the wall), the cost is discounted as the reward (cost_gamma = gamma), "
        "and the strict crossing test's float edge (landing exactly on the wall) is closed."
    )
    out += lines
    out.append("")
    pen_rows = [r for r in rows if r["knob"] == "lambda" and r["runs_ok"]]
    if pen_rows:
        out.append("Against the runs (mean eval cost over seeds; predicted: the penalty-optimal plan):\n")
        out.append("| start | λ | predicted cost | runs: eval cost | check |")
        out.append("|---|---:|---:|---:|---|")
        for r in pen_rows:
            out.append(f"| {r['start']} | {r['value']:g} | {r['predicted_cost']:.2f} | "
                       f"{_pm(r['cost_mean'], r['cost_std'])} | {r['check']} |")
        out.append("")
    out.append("## (b) Why no single lambda enforces 'at most d collisions in expectation'\n")
    for lbl, start in analysis.starts.items():
        jumps = th.jumps(start)
        desc = ", ".join(f"a drop of {p:.3f} at λ = {lam:.4f}" for lam, p in jumps) or "no jump (never crosses)"
        out.append(f"- {lbl}: expected crossings of the penalty-optimal policy = "
                   f"{analysis.unconstrained_cost(lbl):.3f} for small λ; {desc}; 0 beyond.")
    out.append("")
    left = th.threshold[th.x < e.wall_x]
    if left.size and e.wall == "pass":
        out.append(
            f"Per-start thresholds: every start left of the wall has the same λ*(x0) = "
            f"{left.min():.4f}" + (f" to {left.max():.4f}" if left.max() - left.min() > 1e-9 else "")
            + "; starts at or beyond the wall never cross (λ* = 0). "
            "For a fixed λ the penalized problem is an ordinary MDP whose optimal policy is "
            "deterministic: from each start it crosses or it does not. Its expected cost is "
            "therefore a step function of λ, jumping by the probability mass of the starts whose "
            "threshold λ passes. A budget d strictly between two levels of that step function "
            "(here 0 < d < P(x0 < wall)) is met with equality by no λ: a λ below the threshold "
            "gives too many crossings, one above gives none and throws away the reward a budget "
            "d would allow. The constrained optimum crosses with probability d / P(x0 < wall) "
            "(a stochastic policy, optimal for the Lagrangian only at λ = λ* exactly, where "
            "crossing and stopping tie), and which mixture is right depends on the budget and on "
            "ρ0. That λ and mixture are found by adapting λ: dual ascent raises λ while J_c > d "
            "and lowers it while J_c < d, so it settles at the tie, where the policy's mixing "
            "makes J_c = d on average. A hand-set λ would have to hit the tie exactly, and a "
            "different ρ0 (or budget) moves the required mixture."
        )
    con_rows = [r for r in rows if r["knob"] == "d" and r["runs_ok"]]
    if con_rows:
        out.append("\nConstrained runs (ideal cost = min(d, expected crossings of the unconstrained optimum)):\n")
        out.append("| algo | start | d | ideal cost | eval cost | train cost (last 25%) | final λ | check |")
        out.append("|---|---|---:|---:|---:|---:|---:|---|")
        for r in con_rows:
            lam = f"{r['final_lambda_mean']:.2f}" if math.isfinite(r["final_lambda_mean"]) else "n/a"
            out.append(f"| {r['algo']} | {r['start']} | {r['value']:g} | {r['predicted_cost']:.2f} | "
                       f"{_pm(r['cost_mean'], r['cost_std'])} | {_pm(r['train_cost_mean'], r['train_cost_std'])} | "
                       f"{lam} | {r['check']} |")
    return "\n".join(out) + "\n"


# --------------------------------------------------------------------------------------------
# Figure
# --------------------------------------------------------------------------------------------
def figure(path: Path, rows: list[dict[str, Any]], runs: list[Run], analysis: Analysis | None) -> None:
    """Left: eval cost against lambda (penalty runs). Then one panel per start distribution: eval
    cost against d (constrained runs, one colour per algorithm). Each seed is a small dot, the mean
    over seeds a large one (3 seeds: a std bar would mislead)."""
    plt = pyplot()

    starts = sorted({r["start"] for r in rows})
    con_starts = sorted({r["start"] for r in rows if r["knob"] == "d"})
    fig, axes = plt.subplots(1, 1 + max(1, len(con_starts)), figsize=(5.6 * (1 + max(1, len(con_starts))), 4.8),
                             squeeze=False)
    ax_p, con_axes = axes[0][0], axes[0][1:]
    done = [r for r in runs if r.status == OK and r.key is not None]
    budgets = sorted({r["value"] for r in rows if r["knob"] == "d"})
    lam_max = max([r["value"] for r in rows if r["knob"] == "lambda"] + [2.0]) * 1.1
    d_max = max(budgets + [1.0]) * 1.05

    def series(ax, mine, means, x_shift, color, label, marker="o"):
        ax.plot([r.key.value + x_shift for r in mine], [r.eval_cost for r in mine], ".", color=color, alpha=0.45, ms=5)
        if means:
            x, y = map(np.array, zip(*means))
            ax.plot(x + x_shift, y, marker, color=color, ms=7, label=label)

    # Penalty runs: one colour per start distribution, the DP's step function dashed.
    for i, s in enumerate(starts):
        shift = (i - (len(starts) - 1) / 2) * 0.015 * lam_max  # side by side, not on top
        mine = [r for r in done if r.key.knob == "lambda" and r.key.start == s]
        means = sorted((r["value"], r["cost_mean"]) for r in rows
                       if r["knob"] == "lambda" and r["start"] == s and r["runs_ok"])
        if mine:
            series(ax_p, mine, means, shift, f"C{i}", f"runs: mean (dots: seeds), {s}")
        if analysis is not None and s in analysis.starts:
            grid = np.linspace(0.0, lam_max, 600)
            ax_p.plot(grid, analysis.thresholds.expected_cost(analysis.starts[s], grid), "--",
                      color=f"C{i}", alpha=0.8, label=f"penalty-optimal plan (DP), {s}")
    if analysis is not None and analysis.env.wall == "pass":
        lam_star = analysis.thresholds.at(0.1)
        ax_p.axvline(lam_star, color="0.3", lw=0.8)
        ax_p.annotate(f"λ* = {lam_star:.3f}", (lam_star, 1.08), fontsize=8, ha="center")
    for d in budgets:
        ax_p.axhline(d, color="0.6", lw=0.8, ls=":")
        ax_p.annotate(f"d={d:g}", (lam_max, d), fontsize=7, color="0.4", ha="right", va="bottom")
    ax_p.set(xlabel="fixed penalty λ", ylabel="episode cost (crossings), final eval", ylim=(-0.05, 1.15),
             title="Penalty r − λc: cost against λ (dotted: budgets d)")
    if not any(r.key.knob == "lambda" for r in done):
        ax_p.text(0.5, 0.5, "no finished penalty runs", transform=ax_p.transAxes, ha="center")
    if ax_p.get_legend_handles_labels()[0]:
        ax_p.legend(fontsize=7, loc="upper right", bbox_to_anchor=(1.0, 0.93))

    # Constrained runs: a panel per start distribution, one colour per algorithm.
    algos = sorted({r["algo"] for r in rows if r["knob"] == "d"})
    for ax, s in zip(con_axes, con_starts or ["(none)"]):
        ax.plot([0, d_max], [0, d_max], "k--", lw=1, label="ideal: cost = d")
        if analysis is not None and s in analysis.starts:
            cap = analysis.unconstrained_cost(s)
            if cap < d_max:
                grid = np.linspace(0, d_max, 100)
                ax.plot(grid, np.minimum(grid, cap), "k:", lw=1, label="ideal, capped at the λ=0 cost")
        for j, algo in enumerate(algos):
            color = f"C{j + 2}"
            shift = (j - (len(algos) - 1) / 2) * 0.015 * d_max
            mine = [r for r in done if r.key.knob == "d" and r.key.start == s and r.key.algo == algo]
            mine_rows = [r for r in rows if r["knob"] == "d" and r["start"] == s and r["algo"] == algo and r["runs_ok"]]
            if mine:
                series(ax, mine, sorted((r["value"], r["cost_mean"]) for r in mine_rows), shift, color,
                       f"{algo}: eval mean (dots: seeds)")
                tc = sorted((r["value"], r["train_cost_mean"]) for r in mine_rows)
                ax.plot([v + shift for v, _ in tc], [c for _, c in tc], "x", color=color, ms=7,
                        label=f"{algo}: training cost, last 25%")
        ax.set(xlabel="budget d (expected crossings per episode)", ylabel="episode cost (crossings)",
               title=f"Constraint J_c ≤ d, {s}")
        if not any(r.key.knob == "d" and r.key.start == s for r in done):
            ax.text(0.5, 0.5, "no finished constrained runs", transform=ax.transAxes, ha="center")
        ax.legend(fontsize=7, loc="upper left")
    save_figure(fig, path, dpi=110)


# --------------------------------------------------------------------------------------------
def report(dirs: list[Path], out: Path) -> dict[str, Any]:
    """Gather, analyse, write every output; returns what was written and the run counts."""
    runs, records = gather(dirs)
    analysis = analyse(records)
    rows = table_rows(runs, analysis)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(table_markdown(rows))
    write_csv(out / "table.csv", rows)
    write_csv(out / "runs.csv", status_rows(runs))
    (out / "answers.md").write_text(answers_markdown(analysis, rows))
    redo = [r for r in runs if r.status not in (OK, SUPERSEDED) and r.overrides]
    (out / "rerun.sh").write_text("# Runs that did not finish, each run again into <its sweep>/rerun;\n"
                                  "# the report then uses the rerun in place of the original.\n"
                                  + "".join(rerun_command(r.overrides, _sweep_of(r)) + "\n" for r in redo))
    figure(out / "penalty_vs_constraint.png", rows, runs, analysis)
    counts: dict[str, int] = defaultdict(int)
    for r in runs:
        counts[r.status] += 1
    return {"rows": rows, "runs": runs, "counts": dict(counts), "out": out}


def _sweep_of(run: Run) -> Path:
    return Path(run.path) if run.status == MISSING else sweep_dir_of(Path(run.path))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dirs", nargs="+", type=Path, help="sweep directories (searched recursively)")
    parser.add_argument("--out", type=Path, default=None, help="where to write (default: <first dir>/report)")
    args = parser.parse_args(argv)
    for d in args.dirs:
        if not d.is_dir():
            print(f"not a directory: {d}", file=sys.stderr)
            return 2
    out = args.out or args.dirs[0] / "report"
    result = report(args.dirs, out)
    print(table_markdown(result["rows"]))
    counts = result["counts"]
    print("runs: " + ", ".join(f"{counts.get(s, 0)} {s}" for s in ("ok", "failed", "incomplete", "missing"))
          + (f" ({counts[SUPERSEDED]} superseded by reruns)" if counts.get(SUPERSEDED) else ""))
    not_ok = [r for r in result["runs"] if r.status not in (OK, SUPERSEDED)]
    for r in not_ok[:SHOW_NOT_OK]:
        where = r.path if r.status != MISSING else f"{r.path}: {' '.join(r.overrides)}"
        print(f"  {r.status}: {where}" + (f" ({r.error})" if r.error else ""))
    if len(not_ok) > SHOW_NOT_OK:
        print(f"  ... and {len(not_ok) - SHOW_NOT_OK} more: see {out}/runs.csv")
    if not_ok:
        print(f"to run them again: sh {out}/rerun.sh")
    print(f"wrote {out}/table.md, table.csv, runs.csv, answers.md, rerun.sh, penalty_vs_constraint.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
