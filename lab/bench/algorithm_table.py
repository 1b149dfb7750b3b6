"""The algorithm table (docs/algorithms.md): every algorithm, 3 seeds, on three tasks.

    python experiments/benchmarks/algorithm_table.py --run [--task grid|reach1d|velocity ...] [overrides]
    python experiments/benchmarks/algorithm_table.py ROOT [--task grid] [--out DIR]

``--run`` runs each task's Hydra multirun (``configs/experiment/algorithm_table_<sweep>.yaml``,
joblib, 2 jobs) into ``multirun/algorithm_table/<time>/<sweep>/`` and then reports; without it the
report is made again from ROOT's finished runs. ``--task`` picks tasks (default all three); the
grid's part alone (``--task grid``) is the LP-gap table. Overrides go to every sweep.

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
import subprocess
import time
from pathlib import Path
from typing import Any, Sequence

from cmdp_rl.report.compare import load_runs
from cmdp_rl.report.sweeps import RunRecord
from lab.bench.algorithm_rows import (
    FULL_VELOCITY_STEPS,
    OMNISAFE_SOURCE,
    TASKS,
    VELOCITY_SPS,
    grid_rows,
    grid_table,
    plot_task,
    reach1d_rows,
    reach1d_table,
    velocity_rows,
    velocity_table,
)
from lab.sweeps import experiment_sweep_dir

ROOT = Path(__file__).resolve().parents[2]  # the checkout: its train.py, Makefile, docs/ and multirun/


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
