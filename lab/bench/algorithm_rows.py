"""The algorithm table's rows, tables and figures per task (:mod:`lab.bench.algorithm_table` writes
the page): the grid's LP gap, Reach1D's gap to its exact optimum, the velocity task's normalised metrics
beside OmniSafe's published numbers."""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from cmdp_rl.report.compare import curve_band, group_runs
from cmdp_rl.report.metrics import constraint_name
from cmdp_rl.report.plot import pyplot, save_figure
from cmdp_rl.report.safety_metrics import Reference, normalized_scores
from cmdp_rl.report.sweeps import RunRecord
from lab.studies.stats import sample_mean_std
from lab.studies.tables import markdown_table, pm

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
    from cmdp_rl.config.run_config import load_config

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
