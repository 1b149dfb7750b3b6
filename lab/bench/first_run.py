"""The README's first command (`make train`) for several seeds: the figures docs/guide/first_run.md quotes.

    python experiments/benchmarks/first_run.py               # seeds 0-4
    python experiments/benchmarks/first_run.py --seeds 0 1 --out outputs/first_run
    python experiments/benchmarks/first_run.py -- algo.multiplier.lr=0.1   # the recipe with overrides appended

Runs the Makefile's `train` recipe with `seed=S` appended, one run after another, and prints per
seed the training time (eval.json's train_time_s), the eval return, the constrained optimum (the
env's exact solver), the gap to it, and the eval cost against the budget; then how many seeds are
within 5% of the optimum and within budget, and the machine's load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the checkout: its train.py, Makefile, docs/ and multirun/

from cmdp_rl.config.run_config import compose_config  # noqa: E402
from cmdp_rl.report.summary import optimum_of  # noqa: E402

WITHIN = 0.05  # the first-run page's claim (docs/guide/first_run.md): eval return within 5% of the optimum, cost within budget


def make_train_overrides(makefile: Path = ROOT / "Makefile") -> list[str]:
    """The overrides of the Makefile's `train` recipe (`$(PY) train.py <overrides>`)."""
    recipe = re.search(r"^train:.*\n\t\$\(PY\) train\.py (.*)$", makefile.read_text(), re.M)
    return shlex.split(recipe.group(1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--out", default="outputs/first_run", help="run directories go to OUT/s<seed>")
    ap.add_argument("extra", nargs="*", help="train.py overrides appended to the recipe's (after --)")
    args = ap.parse_args()
    overrides = make_train_overrides() + args.extra
    cfg = compose_config(overrides)
    optimum = optimum_of(cfg.env, cfg.algo.cost_limit)
    print(f"python train.py {' '.join(overrides)} seed=S")
    print(f"{os.cpu_count()} cores, load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("| seed | train s | eval return | optimum | gap | eval cost | budget |")
    print("|--:|--:|--:|--:|--:|--:|--:|")
    good, times = 0, []
    for seed in args.seeds:
        run_dir = Path(args.out) / f"s{seed}"
        subprocess.run(
            [sys.executable, "train.py", *overrides, f"seed={seed}", f"hydra.run.dir={run_dir}"],
            cwd=ROOT,
            check=True,
            stdout=subprocess.DEVNULL,
        )
        res = json.loads(
            (ROOT / run_dir / "eval.json").read_text()
            if not run_dir.is_absolute()
            else (run_dir / "eval.json").read_text()
        )
        ret, cost, t = res["episode_return"], res["episode_cost"], res["train_time_s"]
        gap = optimum - ret if optimum is not None else float("nan")
        ok = cost <= cfg.algo.cost_limit and (optimum is None or gap <= WITHIN * abs(optimum))
        good += ok
        times.append(t)
        print(
            f"| {seed} | {t:.1f} | {ret:.3f} | {optimum:.3f} | {gap:.3f} ({gap / optimum:.1%}) | "
            f"{cost:.2f} | {cfg.algo.cost_limit:g} |",
            flush=True,
        )
    print(
        f"{good}/{len(args.seeds)} seeds within {WITHIN:.0%} of the optimum and within budget; "
        f"training {min(times):.1f}-{max(times):.1f} s"
    )
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
