"""The velocity benchmark: ppo, ppo_lag and cpo on HalfCheetah with budget 25, 3 seeds; a table and a PNG.

    python experiments/benchmarks/velocity_benchmark.py --run [overrides]  # the sweep (train.py -m +experiment=velocity_benchmark), then the report
    python experiments/benchmarks/velocity_benchmark.py SWEEP_DIR          # the report again, from finished runs

The sweep is ``configs/experiment/velocity_benchmark.yaml`` (algorithms, seeds, steps); every
train.py option can be overridden. Each run writes its usual outputs under
``multirun/velocity_benchmark/<time>/<algo>_s<seed>/``; the report lands beside them:

- ``table.md`` / ``table.csv``: per algorithm, mean ± std over seeds of the final policy's return
  and cost (eval.json), the training cost rate, and Safety Gym's normalized return, violation and
  cost rate relative to this sweep's own ppo runs (same env, same budget of steps; see
  docs/benchmarks.md).
- ``curves.png``: training episode return, episode cost (budget line drawn) and cost rate against
  env steps, mean over seeds with a min-max band.
"""

from __future__ import annotations

import math
import statistics
from pathlib import Path
from typing import Any

from cmdp_rl.report.plot import pyplot, save_figure
from cmdp_rl.report.safety_metrics import Reference, normalized_scores
from lab.studies import tables
from lab.studies.stats import population_mean_std
from lab.studies.tables import markdown_table, pm
from lab.sweeps import experiment_arg_parser, experiment_sweep_dir, finished_runs

ROOT = Path(__file__).resolve().parents[2]  # the checkout: its train.py, Makefile, docs/ and multirun/
REFERENCE_ALGO = "ppo"


def load_runs(sweep_dir: Path) -> list[dict[str, Any]]:
    """Every finished run under ``sweep_dir``: its config, eval.json and metrics.csv rows."""
    return [
        {
            "dir": run.path,
            "algo": run.get("algo.name"),
            "seed": run.get("seed"),
            "config": run.config,
            "eval": run.eval,
            "rows": run.metrics,
        }
        for run in finished_runs(sweep_dir)
    ]


def summarize(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per algorithm, means and spreads over its seeds; normalized by the ppo runs' means."""
    by_algo: dict[str, list[dict[str, Any]]] = {}
    for run in runs:
        by_algo.setdefault(run["algo"], []).append(run)
    ref = None
    if REFERENCE_ALGO in by_algo:
        ppo = by_algo[REFERENCE_ALGO]
        ref = Reference(
            *(statistics.fmean(r["eval"][k] for r in ppo) for k in ("episode_return", "episode_cost", "cost_rate")),
            source=f"{REFERENCE_ALGO} runs of this sweep",
        )
    table = []
    for algo, group in sorted(by_algo.items(), key=lambda kv: (kv[0] != REFERENCE_ALGO, kv[0])):
        row: dict[str, Any] = {
            "algo": algo,
            "seeds": len(group),
            "steps": group[0]["eval"]["steps"],
            "cost_limit": group[0]["eval"]["cost_limit"],
        }
        for key in ("episode_return", "episode_cost", "cost_rate", "train_time_s"):
            row[key], row[f"{key}_std"] = population_mean_std([r["eval"][key] for r in group])
        per_seed = [
            normalized_scores(
                r["eval"]["episode_return"],
                r["eval"]["episode_cost"],
                r["eval"]["cost_rate"],
                r["eval"]["cost_limit"],
                ref,
            )
            for r in group
        ]
        for key in ("normalized_return", "normalized_violation", "normalized_cost_rate"):
            values = [s[key] for s in per_seed if s[key] is not None]
            row[key], row[f"{key}_std"] = population_mean_std(values)
        table.append(row)
    return table


def write_table(table: list[dict[str, Any]], out: Path) -> str:
    header = [
        "algo",
        "seeds",
        "steps",
        "return (eval)",
        "cost (eval)",
        "cost rate (training)",
        "norm. return",
        "norm. violation",
        "norm. cost rate",
        "minutes / run",
    ]
    cells = [
        [
            r["algo"],
            str(r["seeds"]),
            f"{r['steps']:,}",
            pm(r["episode_return"], r["episode_return_std"], ".1f", missing=""),
            pm(r["episode_cost"], r["episode_cost_std"], ".1f", missing=""),
            pm(r["cost_rate"], r["cost_rate_std"], ".4f", missing=""),
            pm(r["normalized_return"], r["normalized_return_std"], ".2f", missing=""),
            pm(r["normalized_violation"], r["normalized_violation_std"], ".2f", missing=""),
            pm(r["normalized_cost_rate"], r["normalized_cost_rate_std"], ".2f", missing=""),
            f"{r['train_time_s'] / 60:.1f}",
        ]
        for r in table
    ]
    limit = table[0]["cost_limit"] if table else math.nan
    text = markdown_table(header, cells) + (
        f"\n\nBudget d = {limit:g} per episode. Return and cost: the final policy over eval_episodes episodes "
        f"(eval.json), mean ± std over seeds. Normalized metrics relative to the mean of this sweep's "
        f"{REFERENCE_ALGO} runs (Ray et al. 2019; docs/benchmarks.md).\n"
    )
    return tables.write_table(out, text, table)


def plot_curves(runs: list[dict[str, Any]], out: Path) -> Path:
    plt = pyplot()
    import numpy as np

    panels = (
        ("episode_return", "episode return"),
        ("episode_cost", "episode cost"),
        ("cost_rate", "cost rate (training)"),
    )
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    by_algo: dict[str, list[dict[str, Any]]] = {}
    for run in runs:
        by_algo.setdefault(run["algo"], []).append(run)
    for algo, group in sorted(by_algo.items()):
        n = min(len(r["rows"]) for r in group)
        steps = np.array([row["step"] for row in group[0]["rows"][:n]])
        for ax, (key, _) in zip(axes, panels):
            ys = np.array([[row[key] for row in r["rows"][:n]] for r in group])
            # Iterations in which no episode ended log nan (1000-step episodes span several
            # iterations): plot only the iterations where every seed finished episodes.
            ok = np.isfinite(ys).all(axis=0)
            x, ys = steps[ok], ys[:, ok]
            (line,) = ax.plot(x, ys.mean(axis=0), label=f"{algo} ({len(group)} seed{'s' if len(group) > 1 else ''})")
            ax.fill_between(x, ys.min(axis=0), ys.max(axis=0), color=line.get_color(), alpha=0.2)
    limit = runs[0]["eval"]["cost_limit"]
    axes[1].axhline(limit, color="k", linestyle="--", linewidth=1, label=f"budget d = {limit:g}")
    # Linear up to the budget, logarithmic above: an unconstrained run's cost (hundreds) and the
    # constrained runs' distance from d (a few units) both stay readable.
    axes[1].set_yscale("symlog", linthresh=max(limit, 1e-3))
    axes[1].set_ylim(bottom=0)
    task = runs[0]["config"]["env"].get("task", runs[0]["config"]["env"]["name"])
    for ax, (_, title) in zip(axes, panels):
        ax.set_xlabel("env steps")
        ax.set_title(f"{task}: {title}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(fig, out / "curves.png", dpi=120)


def gather(sweep_dir: Path) -> str:
    runs = load_runs(sweep_dir)
    if not runs:
        raise SystemExit(f"no finished runs (eval.json) under {sweep_dir}")
    text = write_table(summarize(runs), sweep_dir)
    png = plot_curves(runs, sweep_dir)
    print(f"\n{text}\nwrote {sweep_dir / 'table.md'}, {sweep_dir / 'table.csv'}, {png}")
    return text


def main() -> None:
    parser = experiment_arg_parser(__doc__)
    gather(experiment_sweep_dir(parser, parser.parse_args(), "velocity_benchmark", ROOT))


if __name__ == "__main__":
    main()
