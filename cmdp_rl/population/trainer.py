"""A population's run: its agents built as their single runs build them, trained through the loop
``trainer.train`` drives (``run/loop.py``: one ``metrics.csv`` row per agent), ``eval.json`` from
``trainer.write_result``, one process for all.
Outputs (docs/population.md): ``agents/<k>_<values>/`` (one single run's directory per agent),
``population.yaml`` (what a resume rebuilds from), ``population.pt`` (the checkpoint: one entry per
agent in a single run's ``checkpoint.pt`` layout, and the shared collector and generators),
``population.json`` (the summary).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import torch
import yaml

from cmdp_rl.config.threads import apply_threads
from cmdp_rl.config.validation import ConfigError
from cmdp_rl.deploy.final_policy import FinalPolicy
from cmdp_rl.population.agent import PopulationAgent
from cmdp_rl.population.env import population_env
from cmdp_rl.population.spec import agent_configs, label, stacked, unbatched, unbatched_head
from cmdp_rl.population.update import AgentUpdates, PopulationPPO
from cmdp_rl.report.metrics import constraint_name
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.run.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET, evaluate_members
from cmdp_rl.run.loop import Members, train_iterations
from cmdp_rl.run.migrations import (
    deploy_node,
    migrate,
    population_from_stacked,
    saved_config_defaults,
    saved_config_nodes,
)
from cmdp_rl.run.ownership import owned
from cmdp_rl.run.resume import check_resume_config, resumed_raw
from cmdp_rl.run.rundir import (
    CHECKPOINT,
    POPULATION_CHECKPOINT,
    POPULATION_CONFIG,
    POPULATION_SUMMARY,
    ensure_writable,
    read_yaml,
)
from cmdp_rl.run.trainer import (
    build_run,
    check_env_contracts,
    checkpoint_entry,
    evaluate_run,
    open_runs,
    restore,
    train,
    write_result,
)

AGENTS_DIR = "agents"


def _own(raw: Mapping[str, Any] | None) -> dict[str, Any]:
    """The population's config as ``population.yaml`` records it: trusting a checkpoint or resuming
    is one command's word, not the population's."""
    raw = copy.deepcopy(dict(raw or {}))
    raw.pop("hydra", None)
    return {**raw, "resume": None, "trust_checkpoint": False}


def agent_dir_name(k: int, overrides: Mapping[str, Any]) -> str:
    return f"{k:03d}_{label(overrides)}".replace("/", "_").replace(" ", "")


def train_population(
    raw: Mapping[str, Any] | None,
    out_dir: str | Path,
    echo: Callable[[str], None] = print,
    resume: bool = False,
    explicit: Iterable[str] = (),
    trust_checkpoint: bool = False,
) -> dict[str, Any]:
    """Train the population that ``raw`` (a composed config with a ``population`` node) describes
    into ``out_dir``; with ``resume``, continue the population in ``out_dir`` from its checkpoint,
    with its own config (``population.yaml``) and, as a run's resume, the options named in
    ``explicit`` taken from ``raw`` where ``run/resume.py`` allows them (``total_steps`` extends
    it); an older format's checkpoint only with ``trust_checkpoint``, which runs code from the file.
    Returns the summary written to ``population.json``."""
    out = Path(out_dir)
    state = None
    if resume:
        if not (out / POPULATION_CONFIG).is_file():
            raise CheckpointError(f"resume: no {POPULATION_CONFIG} in {out}")
        saved_raw = saved_config_nodes(read_yaml(out / POPULATION_CONFIG, "resume"))
        if (out / POPULATION_CHECKPOINT).is_file():
            saved = load_checkpoint(out / POPULATION_CHECKPOINT, trust=trust_checkpoint)
            if "update" in saved:  # the stacked layout predates defaults that its config does not name
                saved_raw = saved_config_defaults(saved_raw)
            state = migrate(saved)
        saved_raw = deploy_node(saved_raw)  # a population.yaml of the flat deployment options (migrations.py)
        deploy = saved_raw.setdefault("deploy", {})
        if state is not None and deploy.get("policy", "auto") == "auto":  # as its agents resolved it (the
            # last iterate, before populations deployed what a run deploys)
            deploy["policy"] = (
                deploy_node(state["agents"][0]["config"])["deploy"]["policy"] if "agents" in state else "last"
            )
        raw = resumed_raw(saved_raw, raw or {}, explicit, out)
        if raw.get("population") != saved_raw.get("population"):
            raise ConfigError(f"population cannot change when resuming {out}")
        for before, after in zip(agent_configs(_own(saved_raw))[1], agent_configs(_own(raw))[1]):
            check_resume_config(before, after)
    raw = _own(raw)
    overrides, cfgs = agent_configs(raw)  # every agent validated: nothing written yet
    apply_threads(cfgs[0])
    why = unbatched(cfgs[0])
    if why is None:  # the action space: on the first agent as built
        probe, agent, _ = build_run(cfgs[0])
        probe.close()
        why = unbatched_head(agent.actor.head)
    if why is None and resume and state is None:
        raise CheckpointError(f"resume: no {POPULATION_CHECKPOINT} in {out}")
    # The directory is this population's alone while it trains (as a run's: run/ownership.py).
    with owned(out, new_run=not resume, overwrite=bool(raw.get("overwrite"))):
        if why is not None:
            return _in_turn(overrides, cfgs, out, why, echo, resume, raw)
        return _stacked(raw, out, state, echo)


def _stacked(
    raw: dict[str, Any], out: Path, state: dict[str, Any] | None, echo: Callable[[str], None]
) -> dict[str, Any]:
    """The batched program: every agent's env, acting and update as one."""
    overrides, cfgs = agent_configs(raw)
    cfg = cfgs[0]
    check_env_contracts(*cfgs)
    device = torch.device(cfg.device)
    P, N, T = len(cfgs), cfg.env.num_envs, cfg.rollout_steps

    # Each agent's networks and algorithm state as its single run builds them, under its seed; the
    # generator state after that is where its single run's action samples and permutations start.
    agents, algos, generators = [], [], []
    for c in cfgs:
        probe, agent, algo = build_run(c)
        probe.close()
        agents.append(agent)
        algos.append(algo)
        g = torch.Generator(device=device)
        g.set_state(torch.get_rng_state() if device.type == "cpu" else torch.cuda.get_rng_state(device))
        generators.append(g)
    env = population_env(cfgs, N, [c.seed for c in cfgs], device)
    pop = PopulationAgent(agents, generators, device)
    one_update = stacked(cfg.algo.name, getattr(cfg.algo, "base", None))
    update = PopulationPPO(pop, algos) if one_update else AgentUpdates(pop, algos)
    collector = Collector(env, pop, T, seed=None)

    dirs = [out / AGENTS_DIR / agent_dir_name(k, ov) for k, ov in enumerate(overrides)]
    ensure_writable(out)  # before population.yaml; each agent's directory is checked as a run's
    (out / POPULATION_CONFIG).write_text(
        yaml.safe_dump({k: v for k, v in raw.items() if k != "resume"}, sort_keys=False)
    )
    names = env.cost_names
    loggers, run_cfgs = open_runs(dirs, cfgs, algos[0].stats, names, state, lambda s: None)

    per_iter = T * N  # steps per agent per iteration
    iterations = math.ceil(cfg.total_steps / per_iter)
    first, elapsed = 1, 0.0
    costs = torch.zeros(P, len(names), dtype=torch.float64)  # every cost each agent collected so far
    if state is not None:
        if "agents" not in state:  # the stacked layout of earlier populations
            fresh = [checkpoint_entry(r, 0, 0, 0.0, a) for r, a in zip(run_cfgs, algos)]
            state = population_from_stacked(state, fresh, {"actor": agents[0].actor, "critics": agents[0].critics})
        first, elapsed = restore(state, update.algos, state["agents"], collector)  # each agent as its run resumes
        update.stack_agents()
        for g, s in zip(generators, state["generators"]):
            g.set_state(s)
        costs = torch.as_tensor(state["costs"], dtype=torch.float64).view(P, len(names))  # a list of P before K costs
        echo(f"resuming population {out} from iteration {state['iteration']}")
    # What each agent deploys, kept on its single-run agent as its run keeps it (final_policy.py).
    finals = [FinalPolicy(c, iterations, e) for c, e in zip(cfgs, state["agents"] if state else [None] * P)]
    echo(
        f"training a population of {P} {cfg.algo.name} agents on {cfg.env.name} ({N} envs each): "
        f"{iterations} iterations of {per_iter} steps per agent ({cfg.algo.describe_update()}), outputs in {out}"
    )
    start = time.perf_counter() - elapsed
    written: dict[int, list[dict[str, Any]]] = {}  # the entries of the last checkpoint, by iteration

    def entries(it: int, time_s: float) -> list[dict[str, Any]]:
        if it in written:  # the final one is the last checkpoint's: built once
            return written[it]
        update.unstack_agents()
        written.clear()
        # an agent's entry: its single run's checkpoint.pt, the collector and random state left to the population's
        steps = collector.total_steps // P
        written[it] = [
            {**f.state_dict(), **checkpoint_entry(r, it, steps, time_s, a), "collector": None, "rng": None}
            for r, a, f in zip(run_cfgs, algos, finals)
        ]
        return written[it]

    def checkpoint(it: int, time_s: float) -> None:
        shared = {"algo": cfg.algo.name, "policy": cfg.policy.name, "population": P, "iteration": it}
        save_checkpoint(
            out / POPULATION_CHECKPOINT,
            {
                **shared,
                "step": collector.total_steps // P,
                "time_s": time_s,
                "agents": entries(it, time_s),
                "collector": collector.state_dict(),
                "generators": [g.get_state() for g in generators],
                "costs": costs,
            },
        )

    def cost_totals(batch: Any) -> list[list[float]]:
        nonlocal costs
        costs = costs + batch.get((keys.NEXT, keys.COST)).reshape(P, -1, len(names)).sum(1).to(costs)
        return costs.tolist()

    def report(it: int, rows: list[dict[str, Any]], dt: float) -> None:
        if it % cfg.log_interval == 0 or it == first or it == iterations:
            returns = [r["episode_return"] for r in rows]
            ep_costs = [r[constraint_name("episode_cost", names[0], len(names))] for r in rows]
            echo(
                f"iteration {it}/{iterations}: {P} agents, {P * per_iter / dt:,.0f} steps/s summed, "
                f"mean episode return {_nanmean(returns):.3f}, cost {_nanmean(ep_costs):.3f}"
            )

    def update_step(batch: Any, it: int) -> list[dict[str, Any]]:
        stats = update.update(batch)
        if any(f.wants(it) for f in finals):  # the actors as their single runs hold them, then as they do
            update.copy_actors(to_modules=True)
            for k, (f, a) in enumerate(zip(finals, agents)):
                f.after_update(a, it, names, lambda line, k=k: echo(f"agent {k}: {line}"))
        return stats

    members = Members(
        cfgs,
        loggers,
        collector,
        update_step,
        cost_totals,
        checkpoint,
        out / POPULATION_CHECKPOINT,
        report=report,
    )
    train_time = train_iterations(members, first, iterations, start)
    steps = collector.total_steps // P

    final_entries = entries(iterations, train_time)  # the last iterates, before the deployed policies
    for f, a in zip(finals, agents):
        f.deploy(a)
    if cfg.deploy.policy == "mixture":  # each agent's mixture as its run evaluates it, one after another
        results = [evaluate_run(c, a) for c, a in zip(cfgs, agents)]
    else:
        update.copy_actors(to_modules=False)  # the deployed actors (an average) into the stacked rows
        results = _evaluate(pop, cfgs, N, device)
    summary_agents = []
    for i, (d, c, result, entry) in enumerate(zip(dirs, cfgs, results, final_entries)):
        # The agent's entry of the population's checkpoint, as its own checkpoint.pt (for evaluate.py;
        # not resumable on its own: the population resumes from population.pt).
        save_checkpoint(d / CHECKPOINT, entry)
        write_result(d, result, c, steps, train_time, costs[i].tolist(), names, None, finals[i].kept)
        summary_agents.append(_agent_summary(out, d, overrides[i], result))
    summary = _summary(out, cfg, P, steps, train_time, start, summary_agents, envs_per_agent=N, iterations=iterations)
    echo(
        f"done: {P} agents x {steps:,} steps in {train_time:.1f}s ({summary['summed_steps_per_s']:,.0f} steps/s "
        f"summed); runs in {out / AGENTS_DIR}, summary {out / POPULATION_SUMMARY}"
    )
    return summary


def _evaluate(pop: PopulationAgent, cfgs: list[Any], n: int, device: torch.device) -> list[dict[str, Any]]:
    """Each agent's single-run evaluation, side by side: min(eval_episodes, num_envs) envs of its own
    seeded with its evaluation seed, which also seeds its action samples."""
    cfg = cfgs[0]
    seeds = [c.seed + EVAL_SEED_OFFSET for c in cfgs]
    eval_env = population_env(cfgs, min(cfg.eval_episodes, n), seeds, device, evaluation=True)
    training, pop.generators = pop.generators, [torch.Generator(device=device).manual_seed(s) for s in seeds]
    limits = [c.algo.cost_limit for c in cfgs]
    try:
        return evaluate_members(
            pop, eval_env, cfg.eval_episodes, cfg.eval_deterministic, limits, cfg.env.termination_metric
        )
    finally:
        pop.generators = training
        eval_env.close()


def _summary(
    out: Path, cfg: Any, P: int, steps: int, train_time: float, start: float, agents: list, **shape: int
) -> dict[str, Any]:
    """``population.json``: the agents, their values and final evaluation, time, summed steps/s."""
    summary = {
        "agents": P,
        "algo": cfg.algo.name,
        **shape,
        "steps_per_agent": steps,
        "steps_summed": steps * P,
        "train_time_s": train_time,
        "summed_steps_per_s": steps * P / train_time,
        "wall_time_s": time.perf_counter() - start,
        "device": str(cfg.device),
        "torch_threads": torch.get_num_threads(),
        "runs": agents,
    }
    (out / POPULATION_SUMMARY).write_text(json.dumps(summary, indent=2))
    return summary


def _agent_summary(out: Path, d: Path, values: Mapping[str, Any], result: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "dir": str(d.relative_to(out)),
        "values": values,
        "episode_return": result["episode_return"],
        "episode_cost": result.get("episode_cost"),
    }


def _in_turn(
    overrides: list[dict[str, Any]],
    cfgs: list[Any],
    out: Path,
    why: str,
    echo: Callable[[str], None],
    resume: bool,
    raw: Mapping[str, Any],
) -> dict[str, Any]:
    """Agents the batched program does not cover (``why``): each trained by the single-run path,
    ``trainer.train``, into its directory, one after another in this process; the numbers of
    separate runs, and none of the batched program's speed. A resume continues each agent as a run
    resumes (from its ``checkpoint.pt``; a finished one is evaluated again, one killed before its
    first checkpoint starts over)."""
    P = len(cfgs)
    dirs = [out / AGENTS_DIR / agent_dir_name(k, ov) for k, ov in enumerate(overrides)]
    if not resume:
        ensure_writable(out)
        (out / POPULATION_CONFIG).write_text(yaml.safe_dump(dict(raw), sort_keys=False))
    echo(f"population: {why}; its {P} agents train one after another, each as its single run, outputs in {out}")
    start = time.perf_counter()
    agents, train_time = [], 0.0
    for k, (d, c) in enumerate(zip(dirs, cfgs)):
        if resume:  # from the agent's checkpoint, or anew in its directory
            c = (
                dataclasses.replace(c, resume=str(d))
                if (d / CHECKPOINT).is_file()
                else dataclasses.replace(c, overwrite=True)
            )
        echo(f"agent {k + 1}/{P} ({label(overrides[k])}):")
        result = train(c, d, echo=echo)
        train_time += result["train_time_s"]
        agents.append(_agent_summary(out, d, overrides[k], result))
    summary = _summary(out, cfgs[0], P, result["steps"], train_time, start, agents)
    echo(
        f"done: {P} agents trained one after another in {summary['wall_time_s']:.1f}s; summary {out / POPULATION_SUMMARY}"
    )
    return summary


def _nanmean(values: list[float]) -> float:
    return torch.tensor(values, dtype=torch.float64).nanmean().item()


__all__ = ["AGENTS_DIR", "train_population"]
