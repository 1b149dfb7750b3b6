"""Does a Lagrangian method's final policy end within budget and near the optimum? The study of
docs/constraint_satisfaction.md: each (CMDP, method) pair over a few seeds, the final policy's gap
to the exact constrained optimum and each constraint's violation, with intervals over the seeds,
and the multiplier's trajectory from metrics.csv.

``experiments/studies/constraint_satisfaction.py`` is the command line; the pieces are here so that
a test or a notebook can run one cell."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy import stats

from lab.studies.constraint_satisfaction_cases import CASES, METHODS

STUDY_USAGE = """The constraint-satisfaction study (docs/constraint_satisfaction.md).

    python experiments/studies/constraint_satisfaction.py --cases reach1d_pass fork --methods ppo_lag ppo_lag/optimistic
    python experiments/studies/constraint_satisfaction.py --cases fork --seeds 0 1 2 -- total_steps=100000
    python experiments/studies/constraint_satisfaction.py ... --figure docs/figures/constraint_satisfaction_lambda.png

One run after another (no parallel jobs), each as `python train.py <case> <method> seed=S <extra>`
would train it; a run whose eval.json exists under --out is read, not retrained. Prints the table
(gap to the optimum and each constraint's relative violation, mean ± 95% t half-width over seeds)
and writes it, with one JSON line per run, under --out.
"""


@dataclass
class Outcome:
    """One run's final policy against the optimum: ``gap`` is ``(J* - J) / |J*|`` (0: optimal;
    negative: above the optimum, which only an over-budget policy can be in expectation);
    ``violation[k]`` is ``(J_c,k - d_k) / d_k`` (positive: over budget)."""

    case: str
    method: str
    seed: int
    ret: float
    optimum: float | None
    costs: list[float]
    budgets: list[float]
    train_time_s: float
    # The deployed policy's exact return and costs (env=fork, env=grid K = 2: no episodes, no
    # sampling noise; a mixture's are the mean of its members'), or None where none is computed.
    exact_ret: float | None = None
    exact_costs: list[float] | None = None

    @property
    def gap(self) -> float:
        return math.nan if self.optimum is None else (self.optimum - self.ret) / abs(self.optimum)

    @property
    def violation(self) -> list[float]:
        return [(c - d) / d if d > 0 else c for c, d in zip(self.costs, self.budgets)]

    @property
    def within(self) -> bool:
        return all(c <= d for c, d in zip(self.costs, self.budgets))


def run_one(case: str, method: str, seed: int, out: Path, extra: Sequence[str] = ()) -> Outcome:
    """Train ``method`` on ``case`` with ``seed`` into ``out`` (reused when its eval.json exists)."""
    from cmdp_rl.config.run_config import compose_config
    from cmdp_rl.run.trainer import train

    overrides = [*CASES[case], *METHODS[method], f"seed={seed}", *extra]
    cfg = compose_config(overrides)
    if not (out / "eval.json").exists():
        out.mkdir(parents=True, exist_ok=True)
        (out / "overrides.txt").write_text(" ".join(overrides) + "\n")
        train(cfg, out, echo=lambda line: None)
    result = json.loads((out / "eval.json").read_text())
    if (result["deterministic"], result["episodes"]) != (cfg.eval_deterministic, cfg.eval_episodes):
        result = _reevaluate(out, cfg, result)
    names = [k.split("/", 1)[1] for k in result if k.startswith("episode_cost/")] or [None]
    costs = [result["episode_cost" if n is None else f"episode_cost/{n}"] for n in names]
    limits = cfg.algo.cost_limit if isinstance(cfg.algo.cost_limit, list) else [cfg.algo.cost_limit] * len(costs)
    return Outcome(
        case,
        method,
        seed,
        float(result["episode_return"]),
        exact_optimum(cfg),
        [float(c) for c in costs],
        [float(d) for d in limits],
        float(result["train_time_s"]),
        *exact_value(out, cfg),
    )


def exact_value(out: Path, cfg) -> tuple[float | None, list[float] | None]:
    """The exact return and costs of a run's deployed policy (its members', weighted: a mixture
    drawn per episode has the weighted mean of its members' values) on env=fork and env=grid K = 2."""
    from cmdp_rl.run.rundir import load_trained
    from lab.studies.fork_policy import members_of, weights_of

    if cfg.env.name == "fork":
        from lab.studies.fork_policy import mixture_gap

        trained = load_trained(out)
        trained.env.close()
        actor = trained.agent.actor
        gap = mixture_gap(members_of(actor), cfg.env.model(), cfg.env.solve(cfg.algo.cost_limit), weights_of(actor))
        return gap.ret, list(gap.costs)
    if cfg.env.name == "grid" and list(cfg.env.costs) == ["hazard_a", "hazard_b"]:
        from cmdp_rl.envs.grid.optimum import solve_constrained
        from cmdp_rl.envs.grid.tabular import grid_cmdp
        from lab.studies.grid_policy import exact_gap

        trained = load_trained(out)
        trained.env.close()
        cmdp = grid_cmdp(tuple(cfg.env.layout), cfg.env.slip, cfg.env.end_prob)
        best = solve_constrained(cmdp, cfg.algo.cost_limit)
        gaps, weights = [], weights_of(trained.agent.actor)
        for member in members_of(trained.agent.actor):
            trained.agent.actor = member
            gaps.append(exact_gap(trained.agent, cmdp, best))
        w = np.asarray(weights)
        return float(w @ [g.ret for g in gaps]), [float(c) for c in w @ np.array([g.costs for g in gaps])]
    return None, None


def exact(o: Outcome) -> Outcome:
    """``o`` with its exact return and costs in place of the evaluation episodes' (as is without them)."""
    if o.exact_ret is None:
        return o
    return dataclasses.replace(o, ret=o.exact_ret, costs=list(o.exact_costs))


def exact_optimum(cfg) -> float | None:
    """J* at the run's budgets: the env's own solver (fork, Reach1D), else env=grid's occupancy LP
    with both hazards (its K = 1 variant has none here)."""
    from cmdp_rl.report.summary import optimum_of

    found = optimum_of(cfg.env, cfg.algo.cost_limit)
    if found is None and cfg.env.name == "grid" and list(cfg.env.costs) == ["hazard_a", "hazard_b"]:
        from cmdp_rl.envs.grid.optimum import solve_constrained
        from cmdp_rl.envs.grid.tabular import grid_cmdp

        cmdp = grid_cmdp(tuple(cfg.env.layout), cfg.env.slip, cfg.env.end_prob)
        found = float(solve_constrained(cmdp, cfg.algo.cost_limit).ret)
    return found


def _reevaluate(out: Path, cfg, result: dict) -> dict:
    """A run trained with other evaluation options: evaluate its deployed policy as ``cfg`` says
    (as evaluate.py would, same seed), keep the training figures, rewrite eval.json."""
    from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET, evaluate
    from cmdp_rl.run.rundir import load_trained

    trained = load_trained(out, num_envs=min(cfg.eval_episodes, cfg.env.num_envs))
    fresh = evaluate(
        trained.agent,
        trained.env,
        cfg.eval_episodes,
        cfg.eval_deterministic,
        seed=cfg.seed + EVAL_SEED_OFFSET,
        cost_limit=cfg.algo.cost_limit,
    )
    trained.env.close()
    kept = {
        k: result[k]
        for k in ("train_time_s", "final_policy", "averaged_iterations", "mixture_iterations", "steps")
        if k in result
    }
    result = {**fresh, **kept}
    (out / "eval.json").write_text(json.dumps(result, indent=2))
    return result


def lambda_trajectory(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(steps, lambdas [T, K])`` from a run's metrics.csv."""
    with open(run_dir / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    cols = [c for c in rows[0] if c.startswith("lagrange_multiplier")]
    steps = np.array([float(r["step"]) for r in rows])
    return steps, np.array([[float(r[c]) for c in cols] for r in rows])


def interval(values: Sequence[float], level: float = 0.95) -> tuple[float, float]:
    """Mean and the half-width of Student's t interval over the seeds (nan for one seed)."""
    v = np.asarray([x for x in values if math.isfinite(x)], dtype=float)
    if v.size == 0:
        return math.nan, math.nan
    if v.size == 1:
        return float(v[0]), math.nan
    half = stats.t.ppf(0.5 + level / 2, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size)
    return float(v.mean()), float(half)


def _pm(values: Sequence[float], pct: bool = True) -> str:
    m, h = interval(values)
    if pct:
        return f"{m:+.1%} ± {h:.1%}" if math.isfinite(h) else f"{m:+.1%}"
    return f"{m:.3f} ± {h:.3f}" if math.isfinite(h) else f"{m:.3f}"


def table(outcomes: Sequence[Outcome]) -> str:
    """Markdown: per (case, method), seeds, return, gap and each violation as mean ± 95% t
    half-width over the seeds, and how many seeds ended within every budget and within 10% of J*."""
    lines = [
        "| CMDP | method | seeds | return | J* | gap to J* | violation (J_c - d)/d | within budget | within budget and 10% |",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|",
    ]
    groups: dict[tuple[str, str], list[Outcome]] = {}
    for o in outcomes:
        groups.setdefault((o.case, o.method), []).append(o)
    for (case, method), os_ in groups.items():
        k = len(os_[0].costs)
        viol = " / ".join(_pm([o.violation[i] for o in os_]) for i in range(k))
        opt = os_[0].optimum
        good = sum(o.within and o.gap <= 0.10 for o in os_)
        lines.append(
            f"| {case} | {method} | {len(os_)} | {_pm([o.ret for o in os_], pct=False)} | "
            f"{'' if opt is None else f'{opt:.3f}'} | {_pm([o.gap for o in os_])} | {viol} | "
            f"{sum(o.within for o in os_)}/{len(os_)} | {good}/{len(os_)} |"
        )
    return "\n".join(lines)


def plot_lambdas(panels: dict[str, dict[str, Path]], path: Path) -> Path:
    """One panel per CMDP (``panels[title][label] = run_dir``): lambda against env steps, every
    constraint's multiplier of every run, side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.2), squeeze=False)
    for ax, (title, runs) in zip(axes[0], panels.items()):
        for label, run_dir in runs.items():
            steps, lams = lambda_trajectory(run_dir)
            for k in range(lams.shape[1]):
                ax.plot(steps, lams[:, k], label=label if lams.shape[1] == 1 else f"{label} λ{k}", lw=1.2)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("env steps")
        ax.set_ylabel("λ")
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=STUDY_USAGE, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["reach1d_pass", "reach1d_block", "fork"], choices=list(CASES))
    ap.add_argument("--methods", nargs="+", default=["ppo_lag"], choices=list(METHODS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--out", default="outputs/constraint_satisfaction")
    ap.add_argument("--existing", action="store_true", help="train nothing: tabulate the runs already under --out")
    ap.add_argument("--figure", help="also draw each case's lambda against steps, first seed, to this PNG")
    ap.add_argument("extra", nargs="*", help="train.py overrides for every run (after --)")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    outcomes = []
    for case in args.cases:
        for method in args.methods:
            for seed in args.seeds:
                run_dir = out / case / method.replace("/", "+") / f"s{seed}"
                if args.existing and not (run_dir / "eval.json").exists():
                    continue
                o = run_one(case, method, seed, run_dir, args.extra)
                outcomes.append(o)
                row = {**dataclasses.asdict(o), "gap": o.gap, "violation": o.violation}
                with open(out / "runs.jsonl", "a") as f:
                    f.write(json.dumps(row) + "\n")
                print(
                    f"{case} {method} s{seed}: return {o.ret:.3f} (J* {o.optimum}), costs {o.costs} "
                    f"(budgets {o.budgets}), gap {o.gap:+.1%}, {o.train_time_s:.0f} s"
                    + ("" if o.exact_ret is None else f"; exact: return {o.exact_ret:.3f}, costs {o.exact_costs}"),
                    flush=True,
                )
    text = table(outcomes)
    if any(o.exact_ret is not None for o in outcomes):  # the deployed policies valued exactly
        text += "\n\nExact values of the deployed policies:\n\n" + table([exact(o) for o in outcomes])
    print(text)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    (out / "table.md").write_text(text + "\n")
    if args.figure:
        first = args.seeds[0]
        panels = {
            case: {
                m: out / case / m.replace("/", "+") / f"s{first}"
                for m in args.methods
                if (out / case / m.replace("/", "+") / f"s{first}" / "metrics.csv").exists()
            }
            for case in args.cases
        }
        print(f"wrote {plot_lambdas(panels, Path(args.figure))}")
