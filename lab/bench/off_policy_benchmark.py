"""The off-policy benchmark: sac_lag and ppo_lag on HalfCheetah velocity (d = 25), 3 seeds each, at
equal env steps; a table and a figure of return, cost and cost rate against env steps and wall time.

    python experiments/benchmarks/off_policy_benchmark.py --run [overrides]  # the sweep (train.py -m +experiment=off_policy_benchmark), then the report
    python experiments/benchmarks/off_policy_benchmark.py SWEEP_DIR          # the report again, from finished runs
    python experiments/benchmarks/off_policy_benchmark.py --smoke            # a few thousand steps per run, to check the pipeline
    python experiments/benchmarks/off_policy_benchmark.py --throughput [N]   # sac_lag's training steps/s on the task, N iterations

The sweep is ``configs/experiment/off_policy_benchmark.yaml``; sac_lag's network and checkpoint
interval on this task are ``configs/tuning/algo/velocity_sac_lag.yaml``. The report, beside the runs:

- ``table.md`` / ``table.csv``: per algorithm, mean ± std over seeds of the final policy's return and
  cost (eval.json), the training cost rate, minutes per run, and training env steps/s (sac_lag: after
  its warm-up, i.e. at the default update-to-data ratio), with the load average when the report ran.
- ``curves.png``: training episode return, episode cost (budget line) and cost rate against env
  steps (top) and against wall-clock seconds (bottom), mean over seeds with a min-max band.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path
from typing import Any

from cmdp_rl.report.plot import pyplot, save_figure
from lab.studies import tables
from lab.studies.stats import population_mean_std
from lab.studies.tables import markdown_table, pm
from lab.sweeps import experiment_arg_parser, experiment_sweep_dir, finished_runs

ROOT = Path(__file__).resolve().parents[2]  # the checkout
SMOKE = ["total_steps=6144", "env.max_steps=200"]  # sac_lag: 5,000 warm-up steps, then 1,144 trained


def load_runs(sweep_dir: Path) -> list[dict[str, Any]]:
    return [
        {
            "algo": run.get("algo.name"),
            "seed": run.get("seed"),
            "config": run.config,
            "eval": run.eval,
            "rows": run.metrics,
        }
        for run in finished_runs(sweep_dir)
    ]


def training_sps(run: dict[str, Any]) -> float:
    """Env steps per second of training, over the iterations that trained (sac_lag: after warm-up)."""
    rows = [
        r
        for r in run["rows"]
        if r.get("gradient_steps", 1) not in (0, None)
        and not (isinstance(r.get("gradient_steps"), float) and math.isnan(r["gradient_steps"]))
    ]
    if len(rows) < 2:
        return math.nan
    return (rows[-1]["step"] - rows[0]["step"]) / (rows[-1]["time_s"] - rows[0]["time_s"])


def summarize(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    by_algo: dict[str, list[dict[str, Any]]] = {}
    for run in runs:
        by_algo.setdefault(run["algo"], []).append(run)
    table = []
    for algo, group in sorted(by_algo.items()):
        row: dict[str, Any] = {
            "algo": algo,
            "seeds": len(group),
            "steps": group[0]["eval"]["steps"],
            "cost_limit": group[0]["eval"]["cost_limit"],
        }
        for key in ("episode_return", "episode_cost", "cost_rate", "train_time_s"):
            row[key], row[f"{key}_std"] = population_mean_std([r["eval"][key] for r in group])
        row["sps"], row["sps_std"] = population_mean_std([training_sps(r) for r in group])
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
        "minutes / run",
        "training steps/s",
    ]
    cells = [
        [
            r["algo"],
            str(r["seeds"]),
            f"{r['steps']:,}",
            pm(r["episode_return"], r["episode_return_std"], ".1f"),
            pm(r["episode_cost"], r["episode_cost_std"], ".1f"),
            pm(r["cost_rate"], r["cost_rate_std"], ".4f"),
            f"{r['train_time_s'] / 60:.1f}",
            pm(r["sps"], r["sps_std"], ".0f"),
        ]
        for r in table
    ]
    limit = table[0]["cost_limit"] if table else math.nan
    load = os.getloadavg()
    text = markdown_table(header, cells) + (
        f"\n\nBudget d = {limit:g} per episode. Return and cost: the final policy over eval_episodes episodes "
        f"(eval.json), mean ± std over seeds. Training steps/s: env steps per wall-clock second over the "
        f"iterations that trained (sac_lag after its warm-up). Load average when reported: "
        f"{load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} (2 cores).\n"
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
    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    by_algo: dict[str, list[dict[str, Any]]] = {}
    for run in runs:
        by_algo.setdefault(run["algo"], []).append(run)
    for algo, group in sorted(by_algo.items()):
        for row_axes, xkey in zip(axes, ("step", "time_s")):
            for ax, (key, _) in zip(row_axes, panels):
                # Iterations without a finished episode log nan: each seed's curve keeps its own
                # finite points, binned on a shared grid for the mean and the band.
                xs = [np.array([r[xkey] for r in run["rows"] if math.isfinite(r[key])]) for run in group]
                ys = [np.array([r[key] for r in run["rows"] if math.isfinite(r[key])]) for run in group]
                if not all(len(x) for x in xs):
                    continue
                grid = np.linspace(max(x[0] for x in xs), min(x[-1] for x in xs), 50)
                interp = np.array([np.interp(grid, x, y) for x, y in zip(xs, ys)])
                (line,) = ax.plot(grid, interp.mean(axis=0), label=f"{algo} ({len(group)} seeds)")
                ax.fill_between(grid, interp.min(axis=0), interp.max(axis=0), color=line.get_color(), alpha=0.2)
    limit = runs[0]["eval"]["cost_limit"]
    task = runs[0]["config"]["env"].get("task", runs[0]["config"]["env"]["name"])
    for row_axes, xlabel in zip(axes, ("env steps", "wall-clock seconds")):
        row_axes[1].axhline(limit, color="k", linestyle="--", linewidth=1, label=f"budget d = {limit:g}")
        for ax, (_, title) in zip(row_axes, panels):
            ax.set_xlabel(xlabel)
            ax.set_title(f"{task}: {title}")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    return save_figure(fig, out / "curves.png", dpi=110)


def gather(sweep_dir: Path) -> str:
    runs = load_runs(sweep_dir)
    if not runs:
        raise SystemExit(f"no finished runs (eval.json) under {sweep_dir}")
    text = write_table(summarize(runs), sweep_dir)
    png = plot_curves(runs, sweep_dir)
    print(f"\n{text}\nwrote {sweep_dir / 'table.md'}, {sweep_dir / 'table.csv'}, {png}")
    return text


def throughput(iterations: int) -> None:
    """sac_lag's training env steps/s on HalfCheetah velocity at the default update-to-data ratio,
    after its warm-up: collect and update ``iterations`` iterations through the trainer's pieces,
    timing wall clock and this process's CPU time (the CPU figure is what a free core would give
    when the machine is shared)."""
    import time

    from cmdp_rl.algos import make_algo
    from cmdp_rl.config.run_config import compose_config
    from cmdp_rl.envs import make_env
    from cmdp_rl.policies import make_agent
    from cmdp_rl.rollout.collector import Collector
    from cmdp_rl.rollout.normalization import make_normalizers

    cfg = compose_config(["+experiment=off_policy_benchmark", "algo=sac_lag"])
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env, make_normalizers(cfg, env), algo=cfg.algo)
    algo = make_algo(cfg.algo, agent)
    collector = Collector(env, agent, cfg.rollout_steps, seed=0, uniform_steps=cfg.algo.warmup_steps)
    while collector.total_steps < cfg.algo.warmup_steps:  # warm-up: random actions, no updates
        batch = collector.collect()
        agent.normalizers.scale_batch(batch)
        algo.update(batch)
        agent.normalizers.update_observation_stats(batch)
    wall, cpu, steps = time.perf_counter(), time.process_time(), collector.total_steps
    for _ in range(iterations):
        batch = collector.collect()
        agent.normalizers.scale_batch(batch)
        algo.update(batch)
        agent.normalizers.update_observation_stats(batch)
    wall, cpu, steps = time.perf_counter() - wall, time.process_time() - cpu, collector.total_steps - steps
    load = os.getloadavg()
    print(
        f"sac_lag, HalfCheetah velocity, utd_ratio {cfg.algo.utd_ratio:g}, batch {cfg.algo.batch_size}, "
        f"networks {cfg.policy.hidden_sizes} {cfg.policy.activation}, {cfg.env.num_envs} envs x "
        f"{cfg.rollout_steps} steps per iteration: {steps} steps in {wall:.1f} s wall "
        f"({steps / wall:.1f} steps/s), {cpu:.1f} s CPU ({steps / cpu:.1f} steps per CPU second); "
        f"load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}"
    )
    env.close()


def main() -> None:
    parser = experiment_arg_parser(__doc__)
    parser.add_argument("--smoke", action="store_true", help="--run with a few thousand steps per run")
    parser.add_argument(
        "--throughput",
        type=int,
        nargs="?",
        const=20,
        default=None,
        metavar="N",
        help="measure sac_lag's training steps/s over N iterations (default 20) and exit",
    )
    args = parser.parse_args()
    if args.throughput is not None:
        return throughput(args.throughput)
    if args.smoke:
        args.run = True
        args.sweep_dir_or_overrides = [*SMOKE, "seed=0,1", *args.sweep_dir_or_overrides]
    gather(experiment_sweep_dir(parser, args, "off_policy_benchmark", ROOT))


if __name__ == "__main__":
    sys.exit(main())
