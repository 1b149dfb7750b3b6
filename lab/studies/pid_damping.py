"""Does Kp > 0 damp PID-Lagrangian's cost overshoot and oscillation? (Stooke, Achiam, Abbeel, 2020)

Reads the runs of a ``+experiment=pid_damping`` sweep (each run's ``config.yaml`` and
``metrics.csv``) and writes, into the sweep directory:

- ``pid_damping.md``: per (Ki, Kp), mean and sample std over seeds of
  * first crossing: the first iteration at which the batch's episode cost J_c is on the other side
    of the budget d than at iteration 1 (the first time the cost crosses the budget line);
  * overshoot: the peak of J_c - d after the first crossing (0 if it never goes above d again),
    and the same peak of its moving average over 5 iterations, which looks past single-batch noise
    (a batch holds only 10 to 100 episodes, each costing 0, 1 or more);
  * violation: the mean of max(0, J_c - d) after the first crossing;
  * oscillation: the mean of |J_c - d| after the first crossing (how far the cost swings around d);
  * the final evaluation's return and cost (``eval.json``);
- ``pid_damping_runs.csv``: the same per run;
- ``pid_damping.png``: episode cost and lambda against steps, one column per Ki, one colour per Kp
  (thin: seeds; thick: their mean), the budget drawn as a dashed line.

Usage::

    python experiments/studies/pid_damping.py --run [hydra overrides...]   # run the sweep, then analyse it
    python experiments/studies/pid_damping.py multirun/pid_damping/<date>  # analyse an existing sweep
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from cmdp_rl.report import sweeps
from cmdp_rl.report.plot import pyplot, save_figure
from cmdp_rl.run.migrations import saved_config_nodes
from lab.studies.stats import count_finite, sample_mean_std
from lab.studies.tables import markdown_table, pm
from lab.sweeps import experiment_arg_parser, experiment_sweep_dir, started_runs

ROOT = Path(__file__).resolve().parents[2]  # the checkout: its train.py, Makefile, docs/ and multirun/
METRICS = ("first_crossing", "overshoot", "overshoot_smooth", "violation", "oscillation", "eval_return", "eval_cost")
SMOOTH = 5  # iterations in the moving average of overshoot_smooth


def load_run(run: sweeps.RunRecord) -> dict:
    cfg, ev = saved_config_nodes(run.config), run.eval or {}  # a sweep's runs from before algo.multiplier too
    gains = cfg["algo"]["multiplier"]
    col = lambda name: np.array([r[name] for r in run.metrics])  # noqa: E731
    return {
        "dir": run.path.name,
        "ki": gains["ki"],
        "kp": gains["kp"],
        "kd": gains["kd"],
        "seed": cfg["seed"],
        "d": cfg["algo"]["cost_limit"],
        "step": col("step"),
        "cost": col("episode_cost"),
        "lam": col("lagrange_multiplier"),
        "eval_return": ev.get("episode_return", math.nan),
        "eval_cost": ev.get("episode_cost", math.nan),
    }


def damping_metrics(cost: np.ndarray, d: float) -> dict[str, float]:
    """First crossing of the budget line and what the cost does after it (see module docstring)."""
    valid = np.flatnonzero(~np.isnan(cost))
    nan = dict.fromkeys(("first_crossing", "overshoot", "overshoot_smooth", "violation", "oscillation"), math.nan)
    if valid.size == 0:
        return nan
    above = cost[valid] > d
    changed = np.flatnonzero(above != above[0])
    if changed.size == 0:
        return nan  # never crossed the budget line
    k0 = valid[changed[0]]
    after = cost[valid[valid >= k0]] - d
    smooth = np.convolve(after, np.ones(SMOOTH) / SMOOTH, mode="valid") if after.size >= SMOOTH else after[:0]
    return {
        "first_crossing": float(k0 + 1),  # iterations are numbered from 1
        "overshoot": float(max(after.max(), 0.0)),
        "overshoot_smooth": float(max(smooth.max(), 0.0)) if smooth.size else math.nan,
        "violation": float(np.maximum(after, 0.0).mean()),
        "oscillation": float(np.abs(after).mean()),
    }


def summarise(runs: list[dict]) -> dict[tuple, dict[str, tuple[float, float, int]]]:
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for run in runs:
        groups[(run["ki"], run["kp"], run["kd"])].append(run)
    table = {}
    for key in sorted(groups):
        table[key] = {}
        for m in METRICS:
            vals = [r[m] for r in groups[key]]
            table[key][m] = (*sample_mean_std(vals), count_finite(vals), len(vals))
    return table


def _fmt(mean: float, std: float, n: int, total: int) -> str:
    return pm(mean, std, ".3g", ".2g", missing="never") + (f" ({n}/{total})" if 0 < n < total else "")


def write_table(table: dict, runs: list[dict], out: Path) -> str:
    d = runs[0]["d"]
    steps = int(max(r["step"][-1] for r in runs))
    intro = (
        f"PID-Lagrangian PPO, Reach1D `env.wall=pass`, budget d = {d}, {steps:,} steps per run; "
        "mean ± sample std over seeds (n/total: runs where the metric exists)."
    )
    header = [
        "Ki",
        "Kp",
        "Kd",
        "seeds",
        "first crossing (iter)",
        "overshoot: peak J_c - d after it",
        f"peak of its {SMOOTH}-iteration mean",
        "violation: mean (J_c - d)+ after it",
        "oscillation: mean abs(J_c - d) after it",
        "eval return",
        "eval cost",
    ]
    cells = [
        [f"{ki:g}", f"{kp:g}", f"{kd:g}", str(row["overshoot"][3]), *(_fmt(*row[m]) for m in METRICS)]
        for (ki, kp, kd), row in table.items()
    ]
    text = intro + "\n\n" + markdown_table(header, cells, "r" * len(header)) + "\n"
    (out / "pid_damping.md").write_text(text)
    with open(out / "pid_damping_runs.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["run", "ki", "kp", "kd", "seed", *METRICS])
        for r in sorted(runs, key=lambda r: (r["ki"], r["kp"], r["kd"], r["seed"])):
            w.writerow([r["dir"], r["ki"], r["kp"], r["kd"], r["seed"], *(r[m] for m in METRICS)])
    return text


def plot(runs: list[dict], out: Path) -> None:
    kis = sorted({r["ki"] for r in runs})
    kps = sorted({(r["kp"], r["kd"]) for r in runs})
    plt = pyplot()
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig, axes = plt.subplots(2, len(kis), figsize=(5.5 * len(kis), 6.5), sharex=True, squeeze=False)
    for j, ki in enumerate(kis):
        for i, (kp, kd) in enumerate(kps):
            group = [r for r in runs if r["ki"] == ki and (r["kp"], r["kd"]) == (kp, kd)]
            if not group:
                continue
            colour = colours[i % len(colours)]
            label = f"Kp = {kp:g}" + (f", Kd = {kd:g}" if kd else "")
            for row, key in enumerate(("cost", "lam")):
                ax = axes[row, j]
                for r in group:
                    ax.plot(r["step"], r[key], color=colour, alpha=0.25, lw=0.8)
                n = min(len(r["step"]) for r in group)
                mean = np.nanmean(np.stack([r[key][:n] for r in group]), axis=0)
                ax.plot(group[0]["step"][:n], mean, color=colour, lw=2.0, label=f"{label} (mean of {len(group)})")
        axes[0, j].axhline(runs[0]["d"], color="black", ls="--", lw=1.2, label=f"budget d = {runs[0]['d']:g}")
        axes[0, j].set_title(f"Ki = {ki:g}")
        axes[0, j].set_ylabel("episode cost J_c (batch mean)")
        axes[1, j].set_ylabel("lambda")
        axes[1, j].set_xlabel("environment steps")
        axes[0, j].legend(fontsize=8)
    fig.suptitle("PID Lagrangian on Reach1D (wall=pass): episode cost and lambda")
    save_figure(fig, out / "pid_damping.png", dpi=110)


def analyse(sweep_dir: Path) -> str:
    runs = [load_run(r) for r in started_runs(sweep_dir)]
    if not runs:
        raise SystemExit(f"no runs (*/metrics.csv) under {sweep_dir}")
    for r in runs:
        r.update(damping_metrics(r["cost"], r["d"]))
    text = write_table(summarise(runs), runs, sweep_dir)
    plot(runs, sweep_dir)
    return text


def main() -> None:
    parser = experiment_arg_parser(__doc__)
    sweep_dir = experiment_sweep_dir(parser, parser.parse_args(), "pid_damping", ROOT)
    print(analyse(sweep_dir))
    print(
        f"wrote {sweep_dir / 'pid_damping.md'}, {sweep_dir / 'pid_damping_runs.csv'}, {sweep_dir / 'pid_damping.png'}"
    )


if __name__ == "__main__":
    main()
