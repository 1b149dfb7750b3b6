"""What the deployed mixture's selection is worth on the generated suite, from finished runs, with no training.

For every run under ``--out`` of ``lab/studies/cmdp_suite.py`` that deployed a mixture with ``weights: feasible``:
each snapshot of the actor is valued exactly (``suite_valuation.action_table`` and backward induction), the weights
are chosen again from the run's own measured values (``deploy/selection.feasible_weights``) under each ``--margins``
value (and, with ``--revalue N``, from N fresh episodes a snapshot), and each choice gets the study's exact verdict
(every cost within its budget, 2% slack; the return at least 90% of J*). The ceiling is the best mixture of the same
snapshots on their exact values: what no selection rule can beat without better snapshots.

    python experiments/studies/suite_deploy_rules.py --out outputs/cmdp_suite [--margins 0 1 1.5 2 3] [--revalue 100]
"""

from __future__ import annotations

import argparse
import copy
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.optimize import linprog

from cmdp_rl.deploy.final_policy import ENTRIES
from cmdp_rl.deploy.mixture import IterateSnapshots
from cmdp_rl.deploy.selection import MemberValue, feasible_weights, value_members
from cmdp_rl.envs.suite.model import evaluate, generate
from lab.studies.cmdp_suite import NEAR, SLACK, split_of

MARGINS = (0.0, 1.0, 1.5, 2.0, 3.0)


@dataclass
class Snapshots:
    """One run's snapshots: their exact values, their measured values (the run's own, and fresh ones), the weights
    the run deployed, and its instance's J* and budgets."""

    run_dir: str
    instance: int
    seed: int
    optimum: float
    budgets: list[float]
    exact_ret: np.ndarray  # [M]
    exact_costs: np.ndarray  # [M, K]
    measured: list[MemberValue]
    deployed: list[float]
    fresh: list[MemberValue] = field(default_factory=list)


def saved_snapshots(run_dir: Path) -> tuple[Any, IterateSnapshots | None, list]:
    """A finished run's ``load_trained`` (its config and agent, the deployed policy put in), its checkpoint's
    snapshots of the actor and one actor per snapshot (None and none where the run did not deploy a mixture)."""
    from cmdp_rl.run.checkpoint import load_checkpoint
    from cmdp_rl.run.migrations import member, migrate
    from cmdp_rl.run.rundir import checkpoint_path, load_trained
    from lab.studies.fork_policy import members_of

    trained = load_trained(run_dir)
    trained.env.close()
    cfg, agent = trained.cfg, trained.agent
    if cfg.deploy.policy != "mixture":
        return trained, None, []
    state = load_checkpoint(checkpoint_path(run_dir, "evaluate"), algo=cfg.algo.name, policy=cfg.policy.name)
    kept = IterateSnapshots(1, 1, 1)
    kept.load_state_dict(member(migrate(state, agent))[ENTRIES["mixture"][0]])
    return trained, kept, kept.actors(members_of(agent.actor)[0])  # the members share one architecture


def load_snapshots(run_dir: Path, revalue: int = 0) -> Snapshots | None:
    """``run_dir``'s snapshots valued exactly (None where the run did not deploy a valued mixture)."""
    from lab.studies.suite_valuation import action_table

    trained, kept, actors = saved_snapshots(run_dir)
    cfg, agent = trained.cfg, trained.agent
    if kept is None or cfg.deploy.weights != "feasible":
        return None
    cmdp, optimum = generate(cfg.env.instance), cfg.env.solve(cfg.algo.cost_limit)
    exact = evaluate(cmdp, np.stack([action_table(a, cmdp, cfg.eval_deterministic) for a in actors]))
    measured = [MemberValue(v["episode_return"], tuple(v["episode_cost"]), tuple(v["cost_se"]), v["episodes"])
                for v in kept.values]  # fmt: skip
    found = Snapshots(
        str(run_dir), cfg.env.instance, cfg.seed, float(optimum.ret), [float(d) for d in optimum.budgets],
        np.asarray(exact.ret, dtype=float), np.asarray(exact.costs, dtype=float).reshape(len(actors), -1),
        measured, list(kept.weights or []),
    )  # fmt: skip
    if revalue:
        more = copy.deepcopy(cfg)
        more.deploy.episodes = revalue
        found.fresh = value_members(actors, agent, more, len(found.budgets))
    return found


def verdict(s: Snapshots, weights: Sequence[float]) -> tuple[bool, bool]:
    """(within every budget, at least 90% of J*) of the mixture with ``weights``, on the exact values."""
    w = np.asarray(weights, dtype=float)
    costs = w @ s.exact_costs
    return all(c <= d * (1 + SLACK) for c, d in zip(costs, s.budgets)), float(w @ s.exact_ret) >= NEAR * s.optimum


def ceiling(s: Snapshots) -> bool:
    """Whether some mixture of the snapshots succeeds on their exact values (the best one within budget)."""
    m = len(s.exact_ret)
    best = linprog(
        -s.exact_ret, A_ub=s.exact_costs.T, b_ub=np.asarray(s.budgets) * (1 + SLACK),
        A_eq=np.ones((1, m)), b_eq=[1.0], bounds=(0, 1), method="highs",
    )  # fmt: skip
    return best.status == 0 and -best.fun >= NEAR * s.optimum


def rule_rows(found: Sequence[Snapshots], margins: Sequence[float]) -> list[tuple[str, list[tuple[bool, bool]]]]:
    """(rule, each run's verdict) for: the weights deployed, each margin on the run's values and on fresh ones,
    and the ceiling (its verdict: success or not)."""
    rows = [("as deployed", [verdict(s, s.deployed) for s in found])]
    sources = [("the run's values", "measured")] + ([("fresh values", "fresh")] if found and found[0].fresh else [])
    for label, attr in sources:
        for m in margins:
            rows.append((f"margin {m:g}, {label}", [verdict(s, feasible_weights(getattr(s, attr), s.budgets, m)[0])
                                                    for s in found]))  # fmt: skip
    rows.append(("ceiling (exact values)", [(ok, ok) for ok in map(ceiling, found)]))
    return rows


def table(found: Sequence[Snapshots], margins: Sequence[float]) -> str:
    """One markdown table per split (tuning and held-aside never pooled): successes, within budget, near J*."""
    lines = []
    for split in ("tuning", "held-aside", "other"):
        mine = [s for s in found if split_of(s.instance) == split]
        if not mine:
            continue
        lines += [
            f"\n{split}: {len(mine)} runs",
            "| rule | success | within budget | >= 90% of J* |",
            "|---|--:|--:|--:|",
        ]
        for rule, verdicts in rule_rows(mine, margins):
            ok = sum(a and b for a, b in verdicts)
            lines.append(f"| {rule} | {ok} | {sum(a for a, _ in verdicts)} | {sum(b for _, b in verdicts)} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", nargs="+", required=True, help="cmdp_suite.py output folders")
    ap.add_argument("--margins", type=float, nargs="+", default=list(MARGINS))
    ap.add_argument("--revalue", type=int, default=0, help="also value each snapshot on this many fresh episodes")
    args = ap.parse_args(argv)
    dirs = sorted({p.parent for out in args.out for p in Path(out).rglob("eval.json")})
    found = [s for s in (load_snapshots(d, args.revalue) for d in dirs) if s is not None]
    if not found:
        raise SystemExit(f"--out: no run that deployed a valued mixture under {' '.join(args.out)}")
    print(table(found, args.margins))
    print(json.dumps({"runs": len(found), "skipped": len(dirs) - len(found)}))
    return 0
