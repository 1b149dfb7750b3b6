"""The Safety-Gymnasium benchmark: ppo, ppo_lag, pid_lag and cpo on SafetyPointGoal1-v0 and
SafetyCarGoal1-v0, budget 25, 3 seeds; per task a table and learning curves, OmniSafe's published
numbers beside them, and env steps/s of our collector against Safety-Gymnasium's own loop.

    python experiments/benchmarks/safety_gym_benchmark.py --run [overrides] [--speed-episodes N]  # the sweep, then the report
    python experiments/benchmarks/safety_gym_benchmark.py SWEEP_DIR [--speed-episodes N]         # the report again

The sweep is ``configs/experiment/safety_gym_benchmark.yaml`` (tasks, algorithms, seeds, steps);
every train.py option can be overridden. Each run writes its usual outputs under
``multirun/safety_gym_benchmark/<time>/<task>_<algo>_s<seed>/``; the report lands beside them:

- ``<task>/table.md``, ``<task>/table.csv``, ``<task>/curves.png``: per algorithm, as the velocity
  benchmark's (``experiments/benchmarks/velocity_benchmark.py``, whose functions make them): mean ± std over
  seeds of the final policy's return and cost, the training cost rate, and the normalized metrics
  relative to this sweep's own ppo runs on the same task;
- ``report.md``: both tables, each with OmniSafe's published return and cost of the same algorithms
  on the same task after 1e7 steps (for orientation: 20x our budget, other hyperparameters), and the
  speed rows: env steps/s of each task in Safety-Gymnasium's own loop (one env) and in our collector
  (``env.num_envs`` envs, the training path; ``experiments/speed/safety_gym_speed.py`` measures both),
  on this machine, with its load average. ``--speed-episodes 0`` leaves the speed rows out.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from lab.bench import safety_gym_speed, velocity_benchmark
from lab.studies.tables import markdown_table
from lab.sweeps import experiment_arg_parser, experiment_sweep_dir

ROOT = Path(__file__).resolve().parents[2]  # the checkout: its train.py, Makefile, docs/ and multirun/
TASKS = ("SafetyPointGoal1-v0", "SafetyCarGoal1-v0")

# OmniSafe's on-policy benchmark, Table 2 (1e7 steps, cost_limit 25; reward and cost, mean ± std over
# their evaluation of several seeds): github.com/PKU-Alignment/omnisafe, benchmarks/on-policy/README.md
# at commit 15603dd (2025-03-17). Their names: PPO, PPOLag, CPPOPID, CPO.
OMNISAFE_SOURCE = (
    "OmniSafe's on-policy benchmark, Table 2 (1e7 steps, cost limit 25): "
    "github.com/PKU-Alignment/omnisafe, benchmarks/on-policy/README.md (commit 15603dd)"
)
OMNISAFE = {
    "SafetyPointGoal1-v0": {
        "ppo": ("PPO", 25.44, 5.43, 55.72, 35.55),
        "ppo_lag": ("PPOLag", 12.96, 6.95, 25.80, 34.99),
        "pid_lag": ("CPPOPID", 8.43, 3.43, 25.74, 7.83),
        "cpo": ("CPO", 20.46, 1.38, 28.84, 7.76),
    },
    "SafetyCarGoal1-v0": {
        "ppo": ("PPO", 33.41, 2.89, 58.06, 42.06),
        "ppo_lag": ("PPOLag", 13.27, 9.26, 21.72, 32.06),
        "pid_lag": ("CPPOPID", 10.60, 2.51, 30.66, 7.53),
        "cpo": ("CPO", 25.52, 2.65, 43.32, 14.35),
    },
}


def package_task(env: dict) -> str:
    """The Safety-Gymnasium id a run trained on: ``env=safe_nav``'s ``PointGoal1`` is the package's
    ``SafetyPointGoal1-v0`` (the same task batched: bit-equal physics, rewards and costs, docs/safe_nav.md)."""
    return f"Safety{env['task']}-v0" if env["name"] == "safe_nav" else env["task"]


def runs_by_task(sweep_dir: Path) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for run in velocity_benchmark.load_runs(sweep_dir):
        out.setdefault(package_task(run["config"]["env"]), []).append(run)
    return out


def omnisafe_table(task: str) -> str:
    rows = [
        [algo, name, f"{r:.2f} ± {rs:.2f}", f"{c:.2f} ± {cs:.2f}"]
        for algo, (name, r, rs, c, cs) in OMNISAFE.get(task, {}).items()
    ]
    return markdown_table(["algo", "OmniSafe's", "return (1e7 steps)", "cost (1e7 steps)"], rows, "llrr")


def speed_rows(tasks: list[str], num_envs: int, episodes: int, safe_nav: bool = False) -> str:
    """Env steps/s of each task: the package's own loop (one env) and our collector (``num_envs``
    envs, sync, random actions), whole episodes each (safety_gym_speed.py's measurements); with
    ``safe_nav``, also the collector on ``env=safe_nav`` (the sweep's env)."""
    before = os.getloadavg()
    rows = []
    for task in tasks:
        steps = safety_gym_speed.TASKS[task] * episodes
        own = safety_gym_speed.single_loop(safety_gym_speed.package_env(task), steps, six=True)
        ours = safety_gym_speed.collector_rate(task, num_envs, steps, "sync")
        row = [task, f"{own:,.0f}", f"{ours:,.0f}", f"{ours / own:.2f}"]
        if safe_nav:
            batched = safety_gym_speed.collector_rate(task, num_envs, steps, "sync", safe_nav=True)
            row += [f"{batched:,.0f}", f"{batched / own:.2f}"]
        rows.append(row)
    after = os.getloadavg()
    head = ["task", "Safety-Gymnasium's loop, 1 env", f"our collector, env=safety_gym, {num_envs} envs", "ratio"]
    if safe_nav:
        head += [f"our collector, env=safe_nav, {num_envs} envs", "ratio"]
    table = markdown_table(head, rows, "l" + "r" * (len(head) - 1))
    return (
        f"{table}\n\nEnv steps/s, {episodes} episode(s) per env, random actions; {os.cpu_count()} cores, "
        f"load average (1, 5, 15 min) before {tuple(round(x, 2) for x in before)}, after "
        f"{tuple(round(x, 2) for x in after)}.\n"
    )


def gather(sweep_dir: Path, speed_episodes: int = 1) -> str:
    by_task = runs_by_task(sweep_dir)
    if not by_task:
        raise SystemExit(f"no finished runs (eval.json) under {sweep_dir}")
    parts = [f"# Safety-Gymnasium benchmark: {sweep_dir}\n"]
    envs = {run["config"]["env"]["name"] for runs in by_task.values() for run in runs}
    if "safe_nav" in envs:
        parts.append(
            "Trained on `env=safe_nav`: the package's tasks batched, with bit-equal physics, rewards "
            "and costs and observations equal to about 1e-15 (docs/safe_nav.md); a same-seed run on "
            "`env=safety_gym` logs the same numbers.\n"
        )
    tasks = sorted(by_task, key=lambda t: (TASKS.index(t) if t in TASKS else len(TASKS), t))  # the config's order
    for task in tasks:
        out = sweep_dir / task
        out.mkdir(exist_ok=True)
        text = velocity_benchmark.write_table(velocity_benchmark.summarize(by_task[task]), out)
        png = velocity_benchmark.plot_curves(by_task[task], out)
        parts += [
            f"## {task}\n",
            text,
            f"Curves: {png.relative_to(sweep_dir)}\n",
            f"For orientation, {OMNISAFE_SOURCE}:\n",
            omnisafe_table(task) + "\n",
        ]
    if speed_episodes > 0:
        num_envs = next(iter(by_task.values()))[0]["config"]["env"]["num_envs"]
        parts += ["## Speed\n", speed_rows(tasks, num_envs, speed_episodes, safe_nav="safe_nav" in envs)]
    report = "\n".join(parts)
    (sweep_dir / "report.md").write_text(report)
    print(f"\n{report}\nwrote {sweep_dir / 'report.md'} and, per task, table.md, table.csv, curves.png")
    return report


def main() -> None:
    parser = experiment_arg_parser(__doc__)
    parser.add_argument(
        "--speed-episodes", type=int, default=1, help="whole episodes per env for the speed rows (0: no speed rows)"
    )
    args, overrides = parser.parse_known_args()
    args.sweep_dir_or_overrides += overrides
    gather(experiment_sweep_dir(parser, args, "safety_gym_benchmark", ROOT), args.speed_episodes)


if __name__ == "__main__":
    main()
