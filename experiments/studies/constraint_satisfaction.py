"""Constraint satisfaction of the Lagrangian methods' final policies on CMDPs with exact optima
(docs/constraint_satisfaction.md; the logic is cmdp_rl/analysis/constraint_satisfaction.py).

    python experiments/studies/constraint_satisfaction.py --cases reach1d_pass fork --methods ppo_lag ppo_lag/optimistic
    python experiments/studies/constraint_satisfaction.py --cases fork --seeds 0 1 2 -- total_steps=100000
    python experiments/studies/constraint_satisfaction.py ... --figure docs/figures/constraint_satisfaction_lambda.png

One run after another (no parallel jobs), each as `python train.py <case> <method> seed=S <extra>`
would train it; a run whose eval.json exists under --out is read, not retrained. Prints the table
(gap to the optimum and each constraint's relative violation, mean ± 95% t half-width over seeds)
and writes it, with one JSON line per run, under --out.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from cmdp_rl.analysis.constraint_satisfaction import CASES, METHODS, exact, plot_lambdas, run_one, table  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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


if __name__ == "__main__":
    main()
