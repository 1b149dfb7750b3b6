"""The algorithm table (docs/algorithms.md): every algorithm, 3 seeds, on three tasks.

    python experiments/benchmarks/algorithm_table.py --run [--task grid|reach1d|velocity ...] [overrides]
    python experiments/benchmarks/algorithm_table.py ROOT [--task grid] [--out DIR]

``--run`` runs each task's Hydra multirun (``configs/experiment/algorithm_table_<sweep>.yaml``,
joblib, 2 jobs) into ``multirun/algorithm_table/<time>/<sweep>/`` and then reports; without it the
report is made again from ROOT's finished runs. ``--task`` picks tasks (default all three); the
grid's part alone (``--task grid``) is issue 15's LP-gap table. Overrides go to every sweep.

- ``grid``: the two-hazard gridworld (K = 2, budgets 0.3 / 0.15) for the algorithms that take K > 1,
  and its K = 1 variant (``env.costs=[hazard_b]``, budget 0.15) for those that take one constraint. Per algorithm: the final policy's return, its gap to the exact LP optimum
  of its variant (``envs/grid/optimum.py``), and each constraint's cost and violation ``max(0, J_c - d)``.
- ``reach1d``: Reach1D, passable wall, budget 0.5 (batched preset): return, cost, training cost rate,
  and the gap to Reach1D's exact constrained optimum.
- ``velocity``: HalfCheetah velocity, budget 25: return, cost, cost rate, Safety Gym's normalised
  metrics against this sweep's ppo runs, OmniSafe's published numbers beside.

The report writes ``algorithms.md`` and ``figures/algorithms_<task>.png`` into ``--out`` (default
ROOT; ``--out docs`` for the repository's docs/algorithms.md), and prints the tables. Where ``--out``
already has an ``algorithms.md`` and ``--task`` names some of the tasks, only those tasks' sections
are replaced (with ``--measured`` at the top of each), so a task measured on another day keeps its own. Every number is
mean ± sample std over seeds, from each run's ``eval.json`` (final policy) and ``metrics.csv``.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import time
from functools import lru_cache
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from cmdp_rl.analysis.stats import sample_mean_std
from cmdp_rl.analysis.tables import markdown_table, pm
from cmdp_rl.report.compare import curve_band, group_runs, load_runs
from cmdp_rl.report.metrics import constraint_name
from cmdp_rl.report.plot import pyplot, save_figure
from cmdp_rl.report.safety_metrics import Reference, normalized_scores
from cmdp_rl.run.sweeps import RunRecord, experiment_sweep_dir

ROOT = Path(__file__).resolve().parents[2]
ALGOS = ("ppo", "penalty", "ppo_lag", "pid_lag", "cpo", "trpo_lag", "pcpo", "crpo", "focops", "cup", "saute")
# task -> its sweeps (configs/experiment/algorithm_table_<sweep>.yaml), run in this order
TASKS = {"grid": ("grid", "grid_k1"), "reach1d": ("reach1d",), "velocity": ("velocity",)}
FULL_VELOCITY_STEPS = 1_000_000
VELOCITY_SPS = 5400  # one HalfCheetah velocity job with a core to itself (docs/benchmarks.md)

# OmniSafe's published on-policy benchmark, SafetyHalfCheetahVelocity-v1 at 1M steps (return, cost),
# mean ± std over their seeds 0, 5, 10, 15, 20 with their hyperparameters: PKU-Alignment/omnisafe,
# benchmarks/on-policy/README.md at commit 31adb38adb522bb1e273449b290404066e12dd93, the "(1M)" tables.
OMNISAFE_SOURCE = (
    "OmniSafe's on-policy benchmark, `benchmarks/on-policy/README.md` of PKU-Alignment/omnisafe "
    "(commit 31adb38), its 1M-step tables for SafetyHalfCheetahVelocity-v1 (5 seeds, their "
    "hyperparameters)"
)
OMNISAFE = {  # ours -> (their name, return, return std, cost, cost std)
    "ppo": ("PPO", 3641.1, 1202.3, 812.8, 219.1),
    "ppo_lag": ("PPOLag", 2065.5, 234.5, 4.7, 5.1),
    "trpo_lag": ("TRPOLag", 1892.77, 505.02, 9.7, 8.51),
    "cpo": ("CPO", 1527.98, 179.73, 87.73, 17.04),
    "pcpo": ("PCPO", 1233.64, 412.36, 23.80, 21.55),
    "focops": ("FOCOPS", 1759.8, 414.4, 31.3, 55.2),
    "cup": ("CUP", 1217.6, 288.0, 15.2, 14.6),
}


def ms(values: Sequence[float]) -> tuple[float, float]:
    return sample_mean_std(values)


def cell(values: Sequence[float], spec: str) -> str:
    return pm(*ms(values), spec, missing="")


def by_algo(runs: Sequence[RunRecord]) -> dict[str, list[RunRecord]]:
    """Finished runs grouped by algorithm (compare.group_runs), in ALGOS order."""
    groups = {g.label.split("=", 1)[1]: g.runs for g in group_runs(runs, ["algo.name"])}
    return {a: groups[a] for a in sorted(groups, key=lambda a: ALGOS.index(a) if a in ALGOS else len(ALGOS))}


def budgets_of(run: RunRecord, names: Sequence[str]) -> list[float]:
    d = run.get("algo.cost_limit")
    return [float(x) for x in d] if isinstance(d, list) else [float(d)] * len(names)


def minutes(group: Sequence[RunRecord]) -> str:
    return cell([r.eval["train_time_s"] / 60 for r in group], ".1f")


# --- grid -------------------------------------------------------------------------------------
@lru_cache(maxsize=None)
def lp_optimum(layout: tuple[str, ...], slip: float, end_prob: float, budgets: tuple[float, ...]) -> float:
    """The exact constrained optimum's return, budgets in grid.COST_NAMES order (inf: unconstrained)."""
    from cmdp_rl.envs.grid.optimum import solve_constrained
    from cmdp_rl.envs.grid.tabular import grid_cmdp

    return float(solve_constrained(grid_cmdp(layout, slip, end_prob), budgets).ret)


def grid_rows(runs: Sequence[RunRecord], variant: str) -> list[dict[str, Any]]:
    from cmdp_rl.envs.grid.env import COST_NAMES

    rows = []
    for algo, group in by_algo(runs).items():
        env = group[0].config["env"]
        names = list(env["costs"])
        limits = dict(zip(names, budgets_of(group[0], names)))
        opt = lp_optimum(
            tuple(env["layout"]), env["slip"], env["end_prob"], tuple(limits.get(c, math.inf) for c in COST_NAMES)
        )
        returns = [r.eval["episode_return"] for r in group]
        row: dict[str, Any] = {
            "task": "grid",
            "variant": variant,
            "algo": algo,
            "seeds": len(group),
            "steps": group[0].eval["steps"],
            "lp_optimum": opt,
            "returns": returns,
            "gaps": [opt - x for x in returns],
            "minutes": minutes(group),
        }
        for c in COST_NAMES:
            if c in names:
                costs = [r.eval[constraint_name("episode_cost", c, len(names))] for r in group]
                row[c] = {"d": limits[c], "costs": costs, "violations": [max(0.0, x - limits[c]) for x in costs]}
        rows.append(row)
    return rows


def grid_table(rows: Sequence[dict[str, Any]]) -> str:
    from cmdp_rl.envs.grid.env import COST_NAMES

    header = [
        "algo",
        "grid",
        "steps",
        "return",
        "LP optimum",
        "gap",
        *[f"{c} (d)" for c in COST_NAMES],
        *[f"violation {c}" for c in COST_NAMES],
        "minutes / run",
    ]
    cells = []
    seen = set()
    for r in rows:
        per = [f"{cell(r[c]['costs'], '.3f')} ({r[c]['d']:g})" if c in r else "not reported" for c in COST_NAMES]
        vio = [cell(r[c]["violations"], ".3f") if c in r else "" for c in COST_NAMES]
        cells.append(
            [
                r["algo"],
                r["variant"],
                f"{r['steps']:,}",
                cell(r["returns"], ".3f"),
                f"{r['lp_optimum']:.3f}",
                cell(r["gaps"], ".3f"),
                *per,
                *vio,
                r["minutes"],
            ]
        )
        seen.add(r["algo"])
    for algo in ALGOS:
        if algo not in seen:
            cells.append([algo, "not run", *[""] * (len(header) - 2)])
    return markdown_table(header, cells)


# --- reach1d and velocity ----------------------------------------------------------------------
def reach1d_rows(runs: Sequence[RunRecord]) -> list[dict[str, Any]]:
    from cmdp_rl.config import load_config

    rows = []
    optimum = None
    for algo, group in by_algo(runs).items():
        if optimum is None:  # the exact constrained optimum of the eval return (Reach1D's solver)
            cfg = load_config({k: v for k, v in group[0].config.items() if k != "resume"})
            optimum = cfg.env.optimum(float(cfg.algo.cost_limit))
        returns = [r.eval["episode_return"] for r in group]
        rows.append(
            {
                "task": "reach1d",
                "algo": algo,
                "seeds": len(group),
                "steps": group[0].eval["steps"],
                "d": float(group[0].get("algo.cost_limit")),
                "returns": returns,
                "optimum": optimum,
                "gaps": [optimum - x for x in returns],
                "costs": [r.eval["episode_cost"] for r in group],
                "cost_rates": [r.eval["cost_rate"] for r in group],
                "minutes": minutes(group),
            }
        )
    return rows


def reach1d_table(rows: Sequence[dict[str, Any]]) -> str:
    header = ["algo", "steps", "return", "gap to optimum", "cost", "within d", "cost rate (training)", "minutes / run"]
    cells = [
        [
            r["algo"],
            f"{r['steps']:,}",
            cell(r["returns"], ".3f"),
            cell(r["gaps"], ".3f"),
            cell(r["costs"], ".2f"),
            f"{sum(c <= r['d'] for c in r['costs'])}/{r['seeds']}",
            cell(r["cost_rates"], ".4f"),
            r["minutes"],
        ]
        for r in rows
    ]
    return markdown_table(header, cells)


def velocity_rows(runs: Sequence[RunRecord]) -> list[dict[str, Any]]:
    groups = by_algo(runs)
    ref = None
    if "ppo" in groups:  # Safety Gym's normalisation against this sweep's own ppo runs
        ppo = groups["ppo"]
        ref = Reference(
            *(float(np.mean([r.eval[k] for r in ppo])) for k in ("episode_return", "episode_cost", "cost_rate")),
            source="ppo runs of this sweep",
        )
    rows = []
    for algo, group in groups.items():
        scores = [
            normalized_scores(
                r.eval["episode_return"], r.eval["episode_cost"], r.eval["cost_rate"], r.eval["cost_limit"], ref
            )
            for r in group
        ]
        norm = {
            k: [s[k] for s in scores if s[k] is not None]
            for k in ("normalized_return", "normalized_violation", "normalized_cost_rate")
        }
        rows.append(
            {
                "task": "velocity",
                "algo": algo,
                "seeds": len(group),
                "steps": group[0].eval["steps"],
                "returns": [r.eval["episode_return"] for r in group],
                "costs": [r.eval["episode_cost"] for r in group],
                "cost_rates": [r.eval["cost_rate"] for r in group],
                **norm,
                "minutes": minutes(group),
            }
        )
    return rows


def velocity_table(rows: Sequence[dict[str, Any]]) -> str:
    header = [
        "algo",
        "steps",
        "return",
        "cost",
        "cost rate",
        "norm. return",
        "norm. violation",
        "norm. cost rate",
        "minutes / run",
        "OmniSafe 1M: return",
        "OmniSafe 1M: cost",
    ]
    cells = []
    for r in rows:
        o = OMNISAFE.get(r["algo"])
        theirs = [f"{o[1]:.1f} ± {o[2]:.1f}", f"{o[3]:.1f} ± {o[4]:.1f}"] if o else ["not published", ""]
        cells.append(
            [
                r["algo"],
                f"{r['steps']:,}",
                cell(r["returns"], ".1f"),
                cell(r["costs"], ".1f"),
                cell(r["cost_rates"], ".4f"),
                cell(r["normalized_return"], ".2f"),
                cell(r["normalized_violation"], ".2f"),
                cell(r["normalized_cost_rate"], ".2f"),
                r["minutes"],
                *theirs,
            ]
        )
    return markdown_table(header, cells)


# --- figures -----------------------------------------------------------------------------------
def plot_task(
    task: str, sweeps: dict[str, Sequence[RunRecord]], out: Path, optima: dict[str, float] | None = None
) -> Path:
    """Training curves per algorithm: return and each cost against env steps, mean over seeds with
    its 95% bootstrap band (compare.curve_band); the budget dashed. Sauté's training return is its
    reshaped return (the eval tables report the task's)."""
    plt = pyplot()
    panels: list[tuple[str, str, float | None]] = [("episode_return", "episode return (training)", None)]
    first = next(r for runs in sweeps.values() for r in runs)
    names = list(first.config["env"].get("costs", ["cost"])) if task == "grid" else ["cost"]
    if task == "grid":
        from cmdp_rl.envs.grid.env import COST_NAMES

        names = list(COST_NAMES)
    for c in names:
        panels.append((c, f"episode cost{'' if c == 'cost' else ': ' + c}", None))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 3.9))
    colors = [*plt.get_cmap("tab10").colors, "black"]  # one color per algorithm of ALGOS (11)
    limits: dict[str, set] = {c: set() for c in names}
    # A velocity episode (1000 steps) ends every 3.9 iterations of 8 x 256 steps, all 8 envs at once:
    # a trailing mean over 8 iterations always holds two episode ends; over 3 it left gaps.
    smoothing = 8 if task == "velocity" else 3
    for s, (sweep, runs) in enumerate(sweeps.items()):
        for algo, group in by_algo(runs).items():
            group = [r for r in group if r.metrics]
            if not group:
                continue
            color = colors[ALGOS.index(algo) % len(colors)] if algo in ALGOS else "k"
            style = "--" if sweep.endswith("_k1") else "-"
            label = f"{algo}{' (K = 1 grid)' if style == '--' else ''}"
            env_costs = list(group[0].config["env"].get("costs", ["cost"])) if task == "grid" else ["cost"]
            series = [("episode_return", 0)]
            for c in env_costs:
                key = constraint_name("episode_cost", c, len(env_costs))
                series.append((key, 1 + names.index(c)))
                for d, cn in zip(budgets_of(group[0], env_costs), env_costs):
                    limits[cn].add(d)
            for key, i in series:
                step, mean, low, high = curve_band(group, key, k=smoothing)
                axes[i].plot(step, mean, style, color=color, lw=1.3, label=label if i == 0 else None)
                axes[i].fill_between(step, low, high, color=color, alpha=0.12, lw=0)
    for j, (label, value) in enumerate(sorted((optima or {}).items())):  # the exact optima, dashed
        axes[0].axhline(value, color="grey", ls=["--", "-."][j % 2], lw=1.2, label=label)
    for i, c in enumerate(names, start=1):
        for d in sorted(limits[c]):
            axes[i].axhline(d, color="black", ls=":", lw=1)
    for ax, (_, title, _) in zip(axes, panels):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    if task == "velocity":
        axes[1].set_yscale("symlog", linthresh=25)
        axes[1].set_ylim(bottom=0)  # costs are >= 0; symlog would show a negative decade
    if task == "grid":  # the task's returns lie in [0, 1]; Sauté's reshaped one (-1 a step once spent) far below
        axes[0].set_ylim(-0.1, 1.0)
        axes[0].set_title("episode return (training; Sauté's reshaped, cut at -0.1)", fontsize=10)
    axes[0].legend(fontsize=7, ncol=2)
    fig.suptitle(f"{task}: mean over seeds, 95% bootstrap band; budgets dotted", fontsize=9)
    out.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, out / f"algorithms_{task}.png", dpi=110)


# --- the document ------------------------------------------------------------------------------
def sweep_runs(root: Path, sweep: str) -> tuple[list[RunRecord], list[RunRecord]]:
    d = root / sweep
    if not d.is_dir():
        return [], []
    return load_runs([d])


def unfinished_note(unfinished: Sequence[RunRecord]) -> str:
    if not unfinished:
        return ""
    listed = ", ".join(f"{r.path.name} ({r.status})" for r in unfinished)
    return f"\n\nNot finished, left out: {listed}."


def report(root: Path, tasks: Sequence[str], out: Path, figures: Path, measured: str) -> str:
    return "\n".join([HEADER.format(measured=measured), *sections(root, tasks, out, figures).values()])


def sections(root: Path, tasks: Sequence[str], out: Path, figures: Path, lead: str = "") -> dict[str, str]:
    """Each task's section of the page (its heading, text, table and figure); ``lead`` opens each."""
    parts: dict[str, str] = {}
    for task in tasks:
        sweeps, unfinished = {}, []
        for sweep in TASKS[task]:
            done, bad = sweep_runs(root, sweep)
            if done:
                sweeps[sweep] = done
            unfinished += bad
        if not sweeps:
            parts[task] = f"## {TITLES[task]}\n\nNo finished runs under {root}/{'/'.join(TASKS[task])}.\n"
            continue
        if task == "grid":
            rows = grid_rows(sweeps.get("grid", []), "K = 2") + grid_rows(sweeps.get("grid_k1", []), "K = 1")
            table = grid_table(rows)
            optima = {f"LP optimum, {r['variant']}": r["lp_optimum"] for r in rows}
        elif task == "reach1d":
            rows = reach1d_rows(sweeps["reach1d"])
            table = reach1d_table(rows)
            optima = {"exact optimum at d": rows[0]["optimum"]} if rows else {}
        else:
            rows = velocity_rows(sweeps["velocity"])
            table = velocity_table(rows)
            optima = {}
        png = plot_task(task, sweeps, figures, optima)
        rel = png.relative_to(out) if out in png.parents else png
        first = next(iter(sweeps.values()))[0]
        text = TEXT[task](rows, first)
        opening = f"{lead}\n\n" if lead else ""
        parts[task] = (
            f"## {TITLES[task]}\n\n{opening}{text['before']}\n\n{table}{unfinished_note(unfinished)}\n\n"
            f"{text['after']}\n\n![{task}]({rel})\n"
        )
    return parts


def splice(page: str, new: dict[str, str]) -> str:
    """``page`` with each task's section (from its heading to the next ``## `` heading) replaced."""
    lines = page.splitlines(keepends=True)
    for task, section in new.items():
        head = f"## {TITLES[task]}"
        start = next((i for i, line in enumerate(lines) if line.rstrip() == head), None)
        if start is None:
            raise SystemExit(f"{head!r} is not in the page: write the whole page (all tasks) instead")
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
        lines[start:end] = [section + "\n"]
    return "".join(lines)


TITLES = {
    "grid": "1. The tabular reference CMDP: gap to the LP optimum (env=grid)",
    "reach1d": "2. Reach1D, passable wall, budget 0.5 (env=reach1d_torch)",
    "velocity": "3. HalfCheetah velocity, budget 25 (env=velocity)",
}

HEADER = """# The on-policy family on three tasks

Every algorithm of the toolkit, 3 seeds (0, 1, 2), with its default options (and the batched Reach1D
preset's tuning files where it has one): `experiments/benchmarks/algorithm_table.py`, which runs the Hydra sweeps
`configs/experiment/algorithm_table_*.yaml` (joblib launcher, 2 jobs side by side, one torch thread
each) and writes this page. Numbers are mean ± sample std over seeds; return and cost are the final
stochastic policy's (`eval.json`, `eval_deterministic=false`: the policy the constraint was enforced
on), the cost rate is the training one (cost per env step over all of training). "Minutes / run" is
the training wall time; jobs shared a 2-core machine with other work, so it is comparable only
roughly. {measured}

Sauté's constraint is almost sure (every episode within budget) where the others' is on the expected
episode cost, so its feasible set is smaller and its optimum lower; its training curve shows the
reshaped return it maximises (the tables: the task's return).
"""


def _grid_text(rows: Sequence[dict[str, Any]], first: RunRecord) -> dict[str, str]:
    episodes = first.get("eval_episodes")
    return {
        "before": (
            f"The slippery two-hazard gridworld (docs/grid.md), 32 envs × 64 steps an iteration, the steps per run "
            f"in the table, {episodes} evaluation episodes. Algorithms that take several constraints run on the K = 2 grid "
            "(budgets hazard_a 0.3, hazard_b 0.15); those that take one (cpo, pcpo, crpo, focops, cup) refuse K > 1 "
            "and run on its K = 1 variant, `env.costs=[hazard_b]` with budget 0.15, a different CMDP with its own "
            "LP optimum. Gap = LP optimum − return (the LP's return is the "
            "expected undiscounted episode return, what `eval.json` reports; docs/grid.md). Violation = "
            "max(0, cost − d) per seed. A negative gap is a return above the constrained optimum, which only a policy "
            "over some budget can have. The hazard-free route's return is 0.528; the unconstrained optimum 0.736."
        ),
        "after": (
            "Reproduce: `python experiments/benchmarks/algorithm_table.py --run --task grid` (the two grid sweeps, then this "
            "table); `python experiments/benchmarks/algorithm_table.py <root> --task grid` prints it again from the runs."
        ),
    }


def _reach1d_text(rows: Sequence[dict[str, Any]], first: RunRecord) -> dict[str, str]:
    steps, episodes = first.eval["steps"], first.get("eval_episodes")
    opt = rows[0]["optimum"] if rows else float("nan")
    return {
        "before": (
            f"Reach1D with `env.wall=pass` (a crossing costs 1), budget d = 0.5 crossings per episode, on the batched "
            f"preset (1024 envs, 32-step rollouts), {steps:,} steps per run, {episodes} evaluation episodes. The exact "
            f"constrained optimum of the return at d = 0.5 is {opt:.3f} (Reach1D's solver, "
            "`Reach1DConfig.optimum`); it mixes crossing and not crossing, which a policy reaches only in "
            "expectation (a negative gap: over the budget). An almost surely safe policy (Sauté) cannot cross at all "
            "at d < 1: its optimum is walking up to the wall."
        ),
        "after": "Reproduce: `python experiments/benchmarks/algorithm_table.py --run --task reach1d`.",
    }


def _velocity_text(rows: Sequence[dict[str, Any]], first: RunRecord) -> dict[str, str]:
    steps = first.eval["steps"]
    if steps < FULL_VELOCITY_STEPS:
        # The estimate rests on docs/benchmarks.md's measurements on this machine (a smoke run's few
        # tiny iterations say nothing about speed): one velocity job trains at about 5,400 steps/s with
        # a core to itself; its 3M-step sweep took 12.1 min a run for ppo and 17.3 for ppo_lag and cpo.
        quiet_h = 33 * FULL_VELOCITY_STEPS / VELOCITY_SPS / 2 / 3600
        status = (
            f"**Not yet measured.** The table below is a smoke run ({steps:,} steps per run, seed and sizes as "
            "its command says) that shows the pipeline end to end; its numbers mean nothing. The full sweep is "
            f"33 runs of 1M steps. At the {VELOCITY_SPS:,} steps/s a velocity job trains at with a core to itself "
            f"(measured on this machine, docs/benchmarks.md), 2 jobs side by side take about {quiet_h:.1f} hours "
            "of training plus evaluation; the second-order and FOCOPS/CUP updates cost more per step (the 3M-step "
            "benchmark took 17.3 min a run for ppo_lag and cpo against 12.1 for ppo), so plan on 2 to 3 hours "
            "on a quiet 2-core machine, several times that while it is shared."
        )
    else:
        status = f"{steps:,} steps per run."
    return {
        "before": (
            "SafetyHalfCheetahVelocity-v1's task (cost 1 per step faster than 3.2096 m/s), budget 25 per 1000-step "
            "episode, 8 envs × 256 steps an iteration, observation normalisation, 20 evaluation episodes; "
            "normalised metrics (Ray et al. 2019) against the mean of this sweep's ppo runs. "
            + status
            + f"\n\nBeside ours, for orientation: {OMNISAFE_SOURCE}. Their step budget is the same, 1M steps; their "
            "hyperparameters, normalisation choices and seeds differ. They publish no row for penalty, pid_lag, "
            "crpo or saute in those tables."
        ),
        "after": (
            "Run it: `python experiments/benchmarks/algorithm_table.py --run --task velocity` (the full sweep); the "
            "smoke run: `python experiments/benchmarks/algorithm_table.py --run --task velocity total_steps=4096 "
            "env.num_envs=2 env.max_steps=100 seed=0 eval_episodes=2`."
        ),
    }


TEXT = {"grid": _grid_text, "reach1d": _reach1d_text, "velocity": _velocity_text}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="store_true", help="run the sweeps first (extra args: Hydra overrides)")
    parser.add_argument("--task", action="append", choices=list(TASKS), help="a task to run/report (repeatable)")
    parser.add_argument("--out", help="where algorithms.md and figures/ go (default: the sweeps' root)")
    parser.add_argument("--measured", default="", help="a sentence on when and at what load (for the page)")
    parser.add_argument("root_or_overrides", nargs="*")
    args = parser.parse_args(argv)
    tasks = args.task or list(TASKS)
    if args.run:
        root = ROOT / "multirun" / "algorithm_table" / time.strftime("%Y-%m-%d_%H-%M-%S")
        given = [o.split("=", 1)[1] for o in args.root_or_overrides if o.startswith("hydra.sweep.dir=")]
        root = Path(given[-1]) if given else root
        overrides = [o for o in args.root_or_overrides if not o.startswith("hydra.sweep.dir=")]
        for task in tasks:
            for sweep in TASKS[task]:
                ns = argparse.Namespace(
                    run=True, sweep_dir_or_overrides=[*overrides, f"hydra.sweep.dir={root / sweep}"]
                )
                try:
                    experiment_sweep_dir(parser, ns, f"algorithm_table_{sweep}", ROOT)
                except subprocess.CalledProcessError as exc:  # a failed job: the report lists it
                    print(f"{sweep}: the sweep exited with {exc.returncode}; reporting what finished")
    else:
        if len(args.root_or_overrides) != 1:
            parser.error("give one root directory (holding grid/, grid_k1/, reach1d/, velocity/), or --run")
        root = Path(args.root_or_overrides[0])
    out = Path(args.out) if args.out else root
    out.mkdir(parents=True, exist_ok=True)
    page = out / "algorithms.md"
    if page.exists() and args.task and set(tasks) != set(TASKS):
        text = splice(page.read_text(), sections(root, tasks, out, out / "figures", args.measured))
    else:
        text = report(root, tasks, out, out / "figures", args.measured)
    page.write_text(text)
    print(text)
    print(f"wrote {out / 'algorithms.md'} and {out / 'figures'}/algorithms_<task>.png")


if __name__ == "__main__":
    main()
