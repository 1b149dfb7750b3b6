"""Algorithms on the generated suite (``env=suite``, ``cmdp_rl/envs/suite/``), judged exactly.

Each (instance, algorithm, seed) is one run as ``python train.py env=suite env.instance=I algo=A
seed=S total_steps=T`` would train it: default options otherwise, the step budget ``T`` the only
one chosen here (:func:`step_budget`). The run deploys what it deploys (its own episodes only); the
instance's exact values then judge it: the deployed policy's return and costs by backward induction
(``envs/suite/valuation.py``) against the LP's ``J*`` at the instance's budgets. A pair succeeds
when every cost is within its budget, 2% slack allowed, and the return is at least 90% of ``J*``
(issue 41's verdict). The exact values never choose anything in a run.

The suite is reported with the tuning instances (``TUNING``, 0..29: may be used to choose
defaults) and the held-aside ones (``HELD_ASIDE``, 1000..1029: never) in separate rows, never
pooled. ``experiments/studies/cmdp_suite.py`` is the command line.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from cmdp_rl.envs.suite.model import HELD_ASIDE, TUNING, generate

USAGE = """Algorithms on the generated suite, judged exactly (docs/constraint_satisfaction.md, "The generated suite").

    python experiments/studies/cmdp_suite.py --instances 0-9 --seeds 0 --algos ppo_lag pid_lag trpo_lag
    python experiments/studies/cmdp_suite.py --instances 0-29 1000-1029 --seeds 0 1 2 --workers 2
    python experiments/studies/cmdp_suite.py --out outputs/cmdp_suite --existing      # tabulate only
    python experiments/studies/cmdp_suite.py --instances 0-9 -- deploy.policy=mixture   # extra overrides

A run whose eval.json exists under --out is read, not retrained. Prints one line per run as it ends,
then the table (per algorithm and split: the share of (CMDP, seed) pairs within every budget, at
>= 90% of J*, and both), and writes runs.jsonl and table.md under --out.
"""

SLACK = 0.02  # a cost at most 2% over its budget counts as within (issue 41)
NEAR = 0.9  # the deployed return must reach this share of J*
EPISODES = 2000  # default step budget: this many episodes of the instance's horizon ...
MIN_STEPS = 102_400  # ... and at least 50 iterations of the default 2048-step batch


def split_of(instance: int) -> str:
    return "tuning" if instance in TUNING else "held-aside" if instance in HELD_ASIDE else "other"


def step_budget(horizon: int, episodes: int = EPISODES, min_steps: int = MIN_STEPS) -> int:
    """``episodes`` episodes of ``horizon`` steps, at least ``min_steps``: proportional to the horizon
    (the same number of episodes on every instance), with a floor so that a short horizon still
    gets enough iterations for a multiplier to move (a 10-step instance gives 200 episodes a batch)."""
    return max(int(min_steps), int(episodes) * int(horizon))


@dataclass
class SuiteRun:
    """One run's deployed policy against its instance's optimum; ``refused`` holds the one-line
    reason where the algorithm does not take the instance (e.g. K > 1 costs for cpo)."""

    instance: int
    algo: str
    seed: int
    split: str
    steps: int
    horizon: int
    num_costs: int
    reward_scale: float
    cost_scales: list[float]
    budget_kind: str
    randomised: bool  # the LP's optimum mixes actions somewhere
    optimum: float
    budgets: list[float]
    ret: float = math.nan  # exact, of the deployed policy
    costs: list[float] = dataclasses.field(default_factory=list)  # exact
    eval_return: float = math.nan  # eval.json's (episodes)
    eval_costs: list[float] = dataclasses.field(default_factory=list)
    multipliers: list[float] | None = None  # lambda at the last iteration (metrics.csv), where the algorithm has one
    lp_multipliers: list[float] = dataclasses.field(default_factory=list)  # lambda* (the LP's duals)
    train_time_s: float = math.nan
    refused: str | None = None

    @property
    def within(self) -> bool:
        return self.refused is None and all(c <= d * (1 + SLACK) for c, d in zip(self.costs, self.budgets))

    @property
    def near(self) -> bool:
        return self.refused is None and self.ret >= NEAR * self.optimum

    @property
    def success(self) -> bool:
        return self.within and self.near

    @property
    def verdict(self) -> str:
        """What went wrong, in a few words: the worst cost's ratio to its budget, the return's share of J*."""
        if self.refused is not None:
            return "refused"
        worst = max(range(len(self.costs)), key=lambda k: self.costs[k] / self.budgets[k])
        parts = [] if self.within else [f"over budget: cost_{worst} {self.costs[worst] / self.budgets[worst]:.2f} x d"]
        if not self.near:
            parts.append(f"return {self.ret / self.optimum:.0%} of J*")
        return "; ".join(parts) or "ok"


def final_multipliers(run_dir: Path) -> list[float] | None:
    """lambda at the run's last iteration (each ``lagrange_multiplier*`` column of metrics.csv)."""
    with open(run_dir / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    cols = [c for c in rows[-1] if c.startswith("lagrange_multiplier")] if rows else []
    values = [rows[-1][c] for c in cols]
    return [float(v) for v in values] if values and all(values) else None


def run_one(
    instance: int,
    algo: str,
    seed: int,
    out: Path,
    episodes: int = EPISODES,
    min_steps: int = MIN_STEPS,
    extra: Sequence[str] = (),
) -> SuiteRun:
    """Train ``algo`` on ``instance`` with ``seed`` into ``out`` (read back where its eval.json
    exists) and judge its deployed policy exactly."""
    from cmdp_rl import train
    from cmdp_rl.config.run_config import ConfigError, compose_config

    model = generate(instance)
    steps = step_budget(model.horizon, episodes, min_steps)
    overrides = ["env=suite", f"env.instance={instance}", f"algo={algo}", f"seed={seed}", f"total_steps={steps}"]
    run = SuiteRun(
        instance, algo, seed, split_of(instance), steps, model.horizon, model.num_costs, model.reward_scale,
        [float(c) for c in model.cost_scales], model.budget_kind, False, math.nan, [float(d) for d in model.budgets],
    )  # fmt: skip
    refusal = out / "refused.txt"
    if refusal.exists():
        return dataclasses.replace(run, refused=refusal.read_text().strip())
    try:
        # a run cut short before its eval.json (an interrupted study) is trained afresh in its directory
        again = ["overwrite=true"] if out.is_dir() and not (out / "eval.json").exists() else []
        cfg = compose_config([*overrides, *extra, *again])
        if not (out / "eval.json").exists():
            out.mkdir(parents=True, exist_ok=True)
            (out / "overrides.txt").write_text(" ".join([*overrides, *extra]) + "\n")
            train(cfg, out, echo=lambda line: None)
    except ConfigError as exc:  # the algorithm does not take this instance (K costs, Discrete actions)
        out.mkdir(parents=True, exist_ok=True)
        refusal.write_text(str(exc) + "\n")
        return dataclasses.replace(run, refused=str(exc))
    return judged(run, cfg, out)


def judged(run: SuiteRun, cfg, out: Path) -> SuiteRun:
    """``run`` with the exact values of the policy the run in ``out`` (of config ``cfg``) deployed."""
    from cmdp_rl.run.rundir import load_trained
    from lab.studies.suite_valuation import deployed_values

    model = generate(run.instance)
    optimum = cfg.env.solve(cfg.algo.cost_limit)
    trained = load_trained(out)
    trained.env.close()
    values = deployed_values(trained.agent, model, cfg.eval_deterministic)
    result = json.loads((out / "eval.json").read_text())
    names = model.cost_names
    keys = ["episode_cost"] if len(names) == 1 else [f"episode_cost/{n}" for n in names]
    return dataclasses.replace(
        run,
        randomised=optimum.randomised,
        optimum=optimum.ret,
        budgets=[float(d) for d in optimum.budgets],
        ret=float(values.ret),
        costs=[float(c) for c in values.costs],
        eval_return=float(result["episode_return"]),
        eval_costs=[float(result[k]) for k in keys],
        multipliers=final_multipliers(out),
        lp_multipliers=[float(x) for x in optimum.multipliers],
        train_time_s=float(result["train_time_s"]),
    )


def run_population(
    instance: int,
    algo: str,
    seeds: Sequence[int],
    out: Path,
    episodes: int = EPISODES,
    min_steps: int = MIN_STEPS,
    extra: Sequence[str] = (),
) -> list[SuiteRun]:
    """:func:`run_one` for every seed at once: one population (cmdp_rl/population/) whose agents are the seeds'
    runs, each the numbers its single run gives (tests/test_population.py), trained as one batched program."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from cmdp_rl import train
    from cmdp_rl.config.run_config import CONFIG_DIR, ConfigError
    from cmdp_rl.population.spec import population
    from cmdp_rl.population.training import agent_dir_name

    model = generate(instance)
    steps = step_budget(model.horizon, episodes, min_steps)
    overrides = ["env=suite", f"env.instance={instance}", f"algo={algo}", f"total_steps={steps}"]
    grid = "population.grid.seed=[" + ",".join(str(s) for s in seeds) + "]"
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        raw = OmegaConf.to_container(compose("config", overrides=[*overrides, *extra, grid]), resolve=True)
    try:
        pop = population({**raw, "overwrite": True})
        dirs = [out / "agents" / agent_dir_name(k, ov) for k, ov in enumerate(pop.overrides)]
        if not all((d / "eval.json").exists() for d in dirs):
            out.mkdir(parents=True, exist_ok=True)
            train(pop, out, echo=lambda line: None)
    except ConfigError:  # refused (K costs, Discrete actions): each seed's run_one records why
        return [run_one(instance, algo, seed, out / f"s{seed}", episodes, min_steps, extra) for seed in seeds]
    runs = []
    for seed, cfg, d in zip(seeds, pop.cfgs, dirs):
        run = SuiteRun(
            instance, algo, seed, split_of(instance), steps, model.horizon, model.num_costs, model.reward_scale,
            [float(c) for c in model.cost_scales], model.budget_kind, False, math.nan, [float(d) for d in model.budgets],
        )  # fmt: skip
        runs.append(judged(run, cfg, d))
    return runs


def row(run: SuiteRun) -> dict:
    """A run as one JSON object: its fields and its verdicts."""
    return {**dataclasses.asdict(run), "within": run.within, "near": run.near, "success": run.success}


def line(run: SuiteRun) -> str:
    if run.refused is not None:
        return f"i{run.instance} {run.algo} s{run.seed}: refused: {run.refused}"
    costs = ", ".join(f"{c:.4g}/{d:.4g}" for c, d in zip(run.costs, run.budgets))
    lam = "" if run.multipliers is None else " lambda " + "/".join(f"{x:.3g}" for x in run.multipliers)
    star = "/".join(f"{x:.3g}" for x in run.lp_multipliers)
    return (
        f"i{run.instance} ({run.split}, H {run.horizon}, K {run.num_costs}, {run.budget_kind}) {run.algo} s{run.seed}: "
        f"return {run.ret:.4g} of J* {run.optimum:.4g} ({run.ret / run.optimum:.0%}), cost/d {costs},{lam} "
        f"(lambda* {star}), {run.steps:,} steps in {run.train_time_s:.0f} s: {run.verdict}"
    )


def table(runs: Sequence[SuiteRun]) -> str:
    """Markdown: per algorithm and split, the (CMDP, seed) pairs run, refused, and the share within
    every budget, at >= 90% of J*, and both (the suite's verdict)."""
    out = [
        "| algorithm | split | pairs | refused | within budget | >= 90% of J* | both | median return / J* "
        "| median final lambda / lambda* |",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|",
    ]
    groups: dict[tuple[str, str], list[SuiteRun]] = {}
    for r in runs:
        groups.setdefault((r.algo, r.split), []).append(r)
    for (algo, split), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1] != "tuning", kv[0][1])):
        ran = [r for r in rs if r.refused is None]
        n = len(ran)

        def share(k: int) -> str:
            return f"{k}/{n} ({k / n:.0%})" if n else "-"

        ratio = f"{np.median([r.ret / r.optimum for r in ran]):.2f}" if n else "-"
        # each binding constraint's (lambda* > 0) final multiplier against the LP's
        lams = [
            lam / star
            for r in ran
            if r.multipliers is not None
            for lam, star in zip(r.multipliers, r.lp_multipliers)
            if star > 1e-9
        ]
        lam_ratio = f"{np.median(lams):.2g}" if lams else "-"
        out.append(
            f"| {algo} | {split} | {n} | {len(rs) - n} | {share(sum(r.within for r in ran))} | "
            f"{share(sum(r.near for r in ran))} | {share(sum(r.success for r in ran))} | {ratio} | {lam_ratio} |"
        )
    return "\n".join(out)


def parse_ids(specs: Sequence[str]) -> list[int]:
    """``["0-9", "1000-1004", "42"]`` as the instance ids, in order."""
    ids: list[int] = []
    for spec in specs:
        lo, _, hi = spec.partition("-")
        if not lo.isdigit() or (hi and not hi.isdigit()):
            raise SystemExit(f"--instances: expected N or N-M with integers >= 0, got {spec!r}")
        ids.extend(range(int(lo), int(hi or lo) + 1))
    return ids


def _job(args: tuple) -> list[SuiteRun]:
    instance, algo, seeds, out, episodes, min_steps, extra = args
    if isinstance(seeds, int):
        return [run_one(instance, algo, seeds, Path(out), episodes, min_steps, extra)]
    return run_population(instance, algo, seeds, Path(out), episodes, min_steps, extra)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=USAGE, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--instances", nargs="+", default=["0-9"], help="ids or ranges, e.g. 0-29 1000-1029")
    ap.add_argument("--algos", nargs="+", default=["ppo_lag", "pid_lag", "trpo_lag"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--episodes", type=int, default=EPISODES, help="step budget: episodes of the instance's horizon")
    ap.add_argument("--min-steps", type=int, default=MIN_STEPS, help="step budget: at least this many steps")
    ap.add_argument("--workers", type=int, default=1, help="runs in parallel processes (each on one torch thread)")
    ap.add_argument("--out", default="outputs/cmdp_suite")
    ap.add_argument("--existing", action="store_true", help="train nothing: tabulate the runs already under --out")
    ap.add_argument(
        "--population", action="store_true", help="each (instance, algorithm)'s seeds as one population: same numbers"
    )
    ap.add_argument("extra", nargs="*", help="train.py overrides for every run (after --)")
    args = ap.parse_args(argv)
    if args.workers < 1:
        raise SystemExit(f"--workers must be at least 1, got {args.workers}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = []
    for instance in parse_ids(args.instances):
        for algo in args.algos:
            if args.population:
                run_dir = out / f"i{instance}" / algo / ("pop_s" + "-".join(map(str, args.seeds)))
                jobs.append(
                    (instance, algo, tuple(args.seeds), str(run_dir), args.episodes, args.min_steps, tuple(args.extra))
                )
                continue
            for seed in args.seeds:
                run_dir = out / f"i{instance}" / algo / f"s{seed}"
                if args.existing and not any((run_dir / f).exists() for f in ("eval.json", "refused.txt")):
                    continue
                jobs.append((instance, algo, seed, str(run_dir), args.episodes, args.min_steps, tuple(args.extra)))
    start = time.perf_counter()
    print(f"{len(jobs)} runs, {args.workers} worker(s); load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    runs: list[SuiteRun] = []
    with open(out / "runs.jsonl", "w") as log:  # this invocation's runs, each as it ends

        def record(run: SuiteRun) -> None:
            runs.append(run)
            log.write(json.dumps(row(run)) + "\n")
            log.flush()
            print(line(run), flush=True)

        if args.workers == 1:
            for job in jobs:
                for run in _job(job):
                    record(run)
        else:
            # spawn, not fork: a forked child would inherit the parent's torch thread pools
            with ProcessPoolExecutor(max_workers=args.workers, mp_context=multiprocessing.get_context("spawn")) as pool:
                for done in as_completed([pool.submit(_job, job) for job in jobs]):
                    for run in done.result():
                        record(run)
    runs.sort(key=lambda r: (r.instance, r.algo, r.seed))
    text = table(runs)
    print(text)
    print(
        f"{time.perf_counter() - start:.0f} s wall; load average after {' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    (out / "table.md").write_text(text + "\n")
    return 0
