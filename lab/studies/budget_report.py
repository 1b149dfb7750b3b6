"""How well does each algorithm of a sweep keep to its budget, during training and after?

Reads every run under a sweep directory (``config.yaml``, ``metrics.csv``, ``eval.json``), groups
the runs by algorithm and budget, and prints a markdown table (also written to
``budget_report.md`` there): the final evaluation's return and cost (mean ± sample std over seeds),
and the fraction of training iterations whose batch mean episode cost J_c was within the budget
(J_c <= d; iterations in which no episode ended are left out). CPO's selling point is
near-feasibility during training, which the last column measures.

Example (CPO against PPO-Lagrangian at one budget, three seeds)::

    python train.py -m algo=cpo,ppo_lag env=reach1d env.wall=pass algo.cost_limit=0.5 \\
        seed=0,1,2 total_steps=150000 hydra.sweep.dir=multirun/cpo_vs_ppo_lag
    python experiments/studies/budget_report.py multirun/cpo_vs_ppo_lag
"""

from __future__ import annotations

import argparse
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from cmdp_rl.report.sweeps import RunRecord
from lab.studies.stats import sample_mean_std
from lab.studies.tables import markdown_table, pm
from lab.sweeps import finished_runs


def run_summary(run: RunRecord) -> dict:
    d = run.get("algo.cost_limit")
    costs = np.array([r["episode_cost"] for r in run.metrics])
    costs = costs[np.isfinite(costs)]  # iterations in which no episode ended log nan
    ev = run.eval
    return {
        "algo": run.get("algo.name"),
        "d": d,
        "seed": run.get("seed"),
        "eval_return": ev["episode_return"],
        "eval_cost": ev["episode_cost"],
        "within_budget": float((costs <= d).mean()) if costs.size else math.nan,
        "train_cost": float(costs.mean()) if costs.size else math.nan,
        "train_time_s": ev.get("train_time_s", math.nan),
    }


def _ms(vals: list[float]) -> str:
    return pm(*sample_mean_std(vals))


def report(sweep_dir: Path) -> str:
    runs = [run_summary(r) for r in finished_runs(sweep_dir)]
    if not runs:
        raise SystemExit(f"no finished runs (*/eval.json) under {sweep_dir}")
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in runs:
        groups[(r["algo"], r["d"])].append(r)
    header = [
        "algo",
        "d",
        "seeds",
        "eval return",
        "eval cost",
        "iterations with J_c <= d",
        "mean training J_c",
        "per-seed within-budget",
    ]
    cells = []
    for (algo, d), g in sorted(groups.items()):
        per_seed = ", ".join(f"s{r['seed']}: {r['within_budget']:.2f}" for r in sorted(g, key=lambda r: r["seed"]))
        cells.append(
            [
                algo,
                f"{d:g}",
                str(len(g)),
                _ms([r["eval_return"] for r in g]),
                _ms([r["eval_cost"] for r in g]),
                _ms([r["within_budget"] for r in g]),
                _ms([r["train_cost"] for r in g]),
                per_seed,
            ]
        )
    text = markdown_table(header, cells, "lrrrrrrl") + "\n"
    (sweep_dir / "budget_report.md").write_text(text)
    return text


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweep_dir", type=Path)
    print(report(parser.parse_args(argv).sweep_dir))


if __name__ == "__main__":
    main()
