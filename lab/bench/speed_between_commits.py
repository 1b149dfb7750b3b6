"""Training throughput of two commits, measured in alternation so that both see the same load.

    python experiments/speed/speed_between_commits.py BASE [NEW] [--rounds 4] [--iterations 6]

Each commit is exported (``git archive``) to a temporary directory and measured in its own Python
process, importing that tree's ``cmdp_rl`` (``PYTHONPATH``), with ``experiments/benchmark_throughput``'s
``train_rate`` of the *new* tree (so both run the same measuring code; it only needs ``compose_config``
and ``train``). The order alternates base/new, new/base, ... and the script prints each round's
ratio and the medians: on a shared machine the per-round ratio is the figure to quote, the absolute
steps/s move with whatever else runs. NEW defaults to the working tree.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the checkout
SETTINGS = {  # label -> train.py overrides (ppo_lag + MLP, as the throughput table)
    "train, gym Reach1D N=8": ["env=reach1d"],
    "train, torch Reach1D N=1024 (preset)": ["env=reach1d_torch"],
}
PROBE = """
import csv, statistics, tempfile, pathlib
import cmdp_rl
from cmdp_rl.config.run_config import compose_config
cfg = compose_config(["algo=ppo_lag", *{overrides!r}, "device=cpu", "threads=1"])
cfg.total_steps = cfg.rollout_steps * cfg.env.num_envs * {iterations}
cfg.eval_episodes, cfg.checkpoint_every = 1, 10**9
with tempfile.TemporaryDirectory() as out:
    cmdp_rl.train(cfg, out, echo=lambda line: None)
    sps = [float(r["sps"]) for r in csv.DictReader(open(pathlib.Path(out) / "metrics.csv"))]
print(statistics.median(sps[1:] or sps))  # the first iteration pays for warm-up
"""


def export(rev: str, into: Path) -> Path:
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True).stdout
    into.mkdir(parents=True)
    with tempfile.TemporaryFile() as f:
        f.write(archive)
        f.seek(0)
        tarfile.open(fileobj=f).extractall(into, filter="data")
    return into


def measure(tree: Path, overrides: list[str], iterations: int) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    code = PROBE.format(overrides=overrides, iterations=iterations)
    out = subprocess.run([sys.executable, "-c", code], cwd=tree, env=env, check=True, capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base")
    ap.add_argument("new", nargs="?", default=None, help="a commit; default: the working tree")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--iterations", type=int, default=6)
    ap.add_argument("--only", choices=["gym", "torch"], default=None, help="measure one setting")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        trees = {
            "base": export(args.base, Path(tmp) / "base"),
            "new": ROOT if args.new is None else export(args.new, Path(tmp) / "new"),
        }
        print(f"base {args.base}, new {args.new or 'working tree'}; load average {os.getloadavg()[0]:.1f} at start")
        for label, overrides in SETTINGS.items():
            if args.only and args.only not in label:
                continue
            rates: dict[str, list[float]] = {"base": [], "new": []}
            for r in range(args.rounds):
                for which in ("base", "new") if r % 2 == 0 else ("new", "base"):
                    rates[which].append(measure(trees[which], overrides, args.iterations))
            ratios = [n / b for n, b in zip(rates["new"], rates["base"])]
            print(
                f"{label}: base {statistics.median(rates['base']):,.0f} steps/s, new "
                f"{statistics.median(rates['new']):,.0f} steps/s (medians); new/base per round "
                + ", ".join(f"{x:.2f}" for x in ratios)
                + f"; median {statistics.median(ratios):.2f}"
            )
        print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
