"""The deployed mixture's selection judged on held-out episodes, for envs with no exact values (the navigation tasks).

Each finished run's snapshots (``deploy.policy: mixture``) are run on ``--episodes`` fresh episodes each (in the
run's evaluation mode, seeded apart from the run's own valuation and evaluation). Then, many times over, each snapshot's episodes
are split at random: ``--valued`` of them play the run's valuation (what ``deploy/selection.feasible_weights``
reads, under each ``--margins`` value), the rest measure the chosen mixture. Printed per run and over all runs: the
measured return and cost of each margin's choice, and how often that cost is over the budget.

    python experiments/studies/heldout_deploy_rules.py RUN_DIR... [--episodes 60] [--valued 21] [--margins 0 1.5 3]

``--valued 21`` is what ``deploy.policy: auto`` buys a 1M-step navigation run (config/deploy.valuation_plan).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from cmdp_rl.deploy.selection import MemberValue, feasible_weights, member_episodes

SEED_OFFSET = 7_000_001  # neither a training seed, the run's valuation's (2,000,003) nor its evaluation's
SPLITS = 200


def snapshot_episodes(run_dir: Path, episodes: int) -> tuple[list[np.ndarray], list[np.ndarray], float]:
    """Each snapshot's episode returns and first costs over at least ``episodes`` fresh episodes, and the budget."""
    from lab.studies.suite_deploy_rules import saved_snapshots

    trained, kept, actors = saved_snapshots(run_dir)
    if kept is None:
        raise SystemExit(f"{run_dir}: the run did not deploy a mixture (deploy.policy={trained.cfg.deploy.policy})")
    cfg = trained.cfg
    mine = member_episodes(actors, trained.agent, cfg, episodes, cfg.seed + SEED_OFFSET)  # return, length, ...
    return [x[:, 0] for x in mine], [x[:, 3] for x in mine], float(np.atleast_1d(cfg.algo.cost_limit)[0])


def split_choice(
    returns: list[np.ndarray], costs: list[np.ndarray], budget: float, valued: int, margin: float, rng
) -> tuple[float, float]:
    """One random split: the mixture ``margin`` chooses on ``valued`` episodes a snapshot, measured on the rest."""
    values, held_r, held_c = [], [], []
    for r, c in zip(returns, costs):
        order = rng.permutation(len(r))
        v, h = order[:valued], order[valued:]
        se = c[v].std(ddof=1) / math.sqrt(valued)
        values.append(MemberValue(float(r[v].mean()), (float(c[v].mean()),), (float(se),), valued))
        held_r.append(r[h].mean())
        held_c.append(c[h].mean())
    w, _ = feasible_weights(values, [budget], margin)
    return float(np.dot(w, held_r)), float(np.dot(w, held_c))


def study(run_dirs: Sequence[Path], episodes: int, valued: int, margins: Sequence[float]) -> str:
    """The per-run lines and the mean over runs of each margin's held-out return, cost and share over budget."""
    rng, lines, totals = np.random.default_rng(0), [], {m: [] for m in margins}
    for run_dir in run_dirs:
        returns, costs, budget = snapshot_episodes(run_dir, episodes)
        if min(len(r) for r in returns) <= valued + 1:
            raise SystemExit(f"--episodes: {episodes} leaves no held-out episodes beside --valued {valued}")
        snaps = " ".join(f"{r.mean():.1f}/{c.mean():.1f}" for r, c in zip(returns, costs))
        lines.append(f"{run_dir}: snapshots (return/cost over {min(map(len, returns))}+ episodes) {snaps}")
        for m in margins:
            got = np.array([split_choice(returns, costs, budget, valued, m, rng) for _ in range(SPLITS)])
            totals[m].append((got[:, 0].mean(), got[:, 1].mean(), (got[:, 1] > budget).mean()))
            lines.append(
                f"  margin {m:g}: {got[:, 0].mean():.2f} / {got[:, 1].mean():.2f}, over budget {totals[m][-1][2]:.0%}"
            )
    lines += ["", f"over {len(run_dirs)} runs: | margin | return | cost | over budget |", "|--:|--:|--:|--:|"]
    for m in margins:
        a = np.array(totals[m])
        lines.append(f"| {m:g} | {a[:, 0].mean():.2f} | {a[:, 1].mean():.2f} | {a[:, 2].mean():.0%} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path, help="finished runs that deployed a mixture")
    ap.add_argument("--episodes", type=int, default=60, help="fresh episodes a snapshot")
    ap.add_argument("--valued", type=int, default=21, help="of which the valuation reads this many")
    ap.add_argument("--margins", type=float, nargs="+", default=[0.0, 1.0, 1.5, 2.0, 3.0])
    args = ap.parse_args(argv)
    print(study(args.runs, args.episodes, args.valued, args.margins))
    return 0
