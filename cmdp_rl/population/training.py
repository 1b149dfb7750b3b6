"""Training a population (docs/population.md): its P agents on the stacked kernel where population/ covers them
(:func:`train_stacked`, through the run's loop, opening and end), else each agent's run one after another; its
directory's ``population.yaml`` and ``population.json``, each agent's run directory under ``agents/``."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import torch
import yaml

from cmdp_rl.config.run_config import RunConfig
from cmdp_rl.config.saved import AGENTS_DIR, CHECKPOINT, POPULATION_CONFIG, POPULATION_SUMMARY
from cmdp_rl.config.threads import apply_threads
from cmdp_rl.population.kernel import StackedKernel
from cmdp_rl.population.spec import Population, label, unbatched, unbatched_head
from cmdp_rl.report.metrics import constraint_name
from cmdp_rl.run.checkpoint import CheckpointError, checkpoint_state, save_checkpoint
from cmdp_rl.run.finish import evaluate_run, write_result
from cmdp_rl.run.loop import Observer, TrainingLoop
from cmdp_rl.run.ownership import owned
from cmdp_rl.run.rundir import ensure_writable
from cmdp_rl.run.start import build_run, check_env_contracts, open_members
from cmdp_rl.run.trainer import train


def agent_dir_name(k: int, overrides: dict[str, Any]) -> str:
    return f"{k:03d}_{label(overrides)}".replace("/", "_").replace(" ", "")


def train_population(
    pop: Population, out: Path, echo: Callable[[str], None] = print, observers: Sequence[Observer] = ()
) -> dict[str, Any]:
    """Train the P agents of ``pop``, each into a run directory ``out/agents/<k>_<values>/`` as its single run
    writes one: on the stacked kernel where population/ covers them, else each agent's run one after another in
    this process (a resume continues each from its own checkpoint). Returns the summary written to
    ``population.json``."""
    cfgs = pop.cfgs
    apply_threads(cfgs[0])
    why = unbatched(cfgs[0])
    if why is None:  # the action space: on the first agent as built
        probe, agent, _ = build_run(cfgs[0])
        probe.close()
        why = unbatched_head(agent.actor.head)
    if why is None and pop.resume and pop.state is None:
        raise CheckpointError(f"resume: no {CHECKPOINT} in {out}")
    dirs = [out / AGENTS_DIR / agent_dir_name(k, ov) for k, ov in enumerate(pop.overrides)]
    # The directory is this population's alone while it trains (as a run's: run/ownership.py).
    with owned(out, new_run=not pop.resume, overwrite=bool(pop.raw.get("overwrite"))):
        if not pop.resume or why is None:
            ensure_writable(out)  # before population.yaml; each agent's directory is checked as a run's
            saved = {k: v for k, v in pop.raw.items() if k != "resume"}
            (out / POPULATION_CONFIG).write_text(yaml.safe_dump(saved, sort_keys=False))
        start = time.perf_counter()
        if why is None:
            check_env_contracts(*cfgs)
            kernel = StackedKernel(cfgs, torch.device(cfgs[0].device))
            steps, train_time, results = train_stacked(cfgs, out, dirs, pop.state, kernel, echo, observers)
        else:  # the numbers of separate runs, and none of the batched program's speed
            echo(
                f"population: {why}; its {len(cfgs)} agents train one after another, each as its single run, "
                f"outputs in {out}"
            )
            results = _train_each(pop, dirs, echo, observers)
            steps, train_time = results[-1]["steps"], sum(r["train_time_s"] for r in results)
        summary = _summary(pop, out, dirs, results, steps, train_time, time.perf_counter() - start, why is None)
        (out / POPULATION_SUMMARY).write_text(json.dumps(summary, indent=2))
        echo(
            f"done: {len(cfgs)} agents x {steps:,} steps in {train_time:.1f}s ({summary['summed_steps_per_s']:,.0f} "
            f"steps/s summed); runs in {out / AGENTS_DIR}, summary {out / POPULATION_SUMMARY}"
        )
    return summary


def _train_each(
    pop: Population, dirs: list[Path], echo: Callable[[str], None], observers: Sequence[Observer]
) -> list[dict[str, Any]]:
    """Each agent's single run in turn (a resume: from the agent's checkpoint, a finished one evaluated again,
    or anew); their evaluations."""
    results = []
    for k, (d, c) in enumerate(zip(dirs, pop.cfgs)):
        if pop.resume:
            resumed = (d / CHECKPOINT).is_file()
            c = dataclasses.replace(c, resume=str(d) if resumed else None, overwrite=not resumed)
        echo(f"agent {k + 1}/{len(pop.cfgs)} ({label(pop.overrides[k])}):")
        results.append(train(c, d, echo=echo, observers=observers))
    return results


def _summary(
    pop: Population,
    out: Path,
    dirs: list[Path],
    results: list[dict[str, Any]],
    steps: int,
    train_time: float,
    wall_time: float,
    together: bool,
) -> dict[str, Any]:
    """``population.json``: the agents, their steps and speed, and each agent's directory, values and result."""
    cfg, P = pop.cfgs[0], len(pop.cfgs)
    runs = [
        {"dir": str(d.relative_to(out)), "values": ov, **{k: r.get(k) for k in ("episode_return", "episode_cost")}}
        for d, ov, r in zip(dirs, pop.overrides, results)
    ]
    iterations = math.ceil(cfg.total_steps / (cfg.rollout_steps * cfg.env.num_envs))
    return {
        "agents": P,
        "algo": cfg.algo.name,
        **({"envs_per_agent": cfg.env.num_envs, "iterations": iterations} if together else {}),
        "steps_per_agent": steps,
        "steps_summed": steps * P,
        "train_time_s": train_time,
        "summed_steps_per_s": steps * P / train_time,
        "wall_time_s": wall_time,
        "device": str(cfg.device),
        "torch_threads": torch.get_num_threads(),
        "runs": runs,
    }


class ProgressLines:
    """A population's progress: every ``log_interval`` iterations (and its first and last), the agents' summed
    speed and their mean episode return and cost, as an observer of the loop's rows."""

    def __init__(self, cfg: RunConfig, first: int, names: tuple[str, ...], echo: Callable[[str], None]) -> None:
        self.cfg, self.first, self.echo = cfg, first, echo
        self.keys = ("episode_return", constraint_name("episode_cost", names[0], len(names)))

    def __call__(self, it: int, iterations: int, rows: list[dict[str, Any]]) -> None:
        if it % self.cfg.log_interval == 0 or it == self.first or it == iterations:
            mean = [torch.tensor([r[k] for r in rows], dtype=torch.float64).nanmean().item() for k in self.keys]
            summed = len(rows) * rows[0]["sps"]  # each agent's rows: the same steps in the same time
            self.echo(
                f"iteration {it}/{iterations}: {len(rows)} agents, {summed:,.0f} steps/s summed, "
                f"mean episode return {mean[0]:.3f}, cost {mean[1]:.3f}"
            )


def train_stacked(
    cfgs: list[RunConfig],
    out: Path,
    dirs: list[Path],
    state: dict | None,
    kernel: StackedKernel,
    echo: Callable[[str], None],
    observers: Sequence[Observer] = (),
) -> tuple[int, float, list[dict[str, Any]]]:
    """The agents ``cfgs`` on ``kernel``, each into its directory of ``dirs``, checkpointing into ``out``'s;
    returns each agent's steps, the training time and each agent's evaluation."""
    cfg, P, names = cfgs[0], len(cfgs), kernel.env.cost_names
    iterations = math.ceil(cfg.total_steps / kernel.per_iter)
    opened = open_members(cfgs, dirs, kernel, state, iterations, lambda line: None)  # no agent's rows printed
    start = time.perf_counter() - opened.elapsed
    if state is not None:
        echo(f"resuming population {out} from iteration {state['iteration']}")
    echo(
        f"training a population of {P} {cfg.algo.name} agents on {cfg.env.name} ({cfg.env.num_envs} envs each): "
        f"{iterations} iterations of {kernel.per_iter} steps per agent ({cfg.algo.describe_update()}), outputs in {out}"
    )
    member_echoes = [lambda line, k=k: echo(f"agent {k}: {line}") for k in range(P)]
    lines = ProgressLines(cfg, opened.first, names, echo)
    loop = TrainingLoop(
        cfgs,
        opened.saved,
        kernel,
        opened.loggers,
        opened.finals,
        out,
        iterations,
        echo,
        member_echoes,
        observers=[lines, *observers],
    )
    train_time = loop.run(opened.first, start)
    steps = kernel.collector.total_steps // P
    if opened.first > iterations:
        echo(f"{out}: training had already finished at iteration {opened.first - 1}; evaluating")
    entries = loop.entries(iterations)  # each agent's last iterate, before the deployed policies go in
    for f, a in zip(opened.finals, kernel.agents):
        f.deploy(a)
    if cfg.deploy.policy == "mixture":  # each agent's mixture as its run evaluates it
        results = [evaluate_run(c, a) for c, a in zip(cfgs, kernel.agents)]
    else:
        results = kernel.evaluate(cfgs, torch.device(cfg.device))
    totals = kernel.cost_totals()
    for k, (d, c, result, f) in enumerate(zip(dirs, cfgs, results, opened.finals)):
        # the agent's entry of the last checkpoint as its own: it evaluates; the population resumes
        save_checkpoint(d / CHECKPOINT, checkpoint_state(c, iterations, steps, train_time, [entries[k]], None, None))
        write_result(d, result, c, steps, train_time, totals[k], names, None, f.kept)
        opened.loggers[k].finish(result)  # the summary beside the metrics (logger=wandb)
    return steps, train_time, results
