"""A run: env -> collector -> batch -> advantages -> update -> logger, through the loop that runs
and populations share (``run/loop.py``), then the evaluation.

``train.py`` is a thin Hydra front for :func:`train`; a user's script can call it directly.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import torch
import yaml

from cmdp_rl.algos import make_algo
from cmdp_rl.algos.base import per_constraint
from cmdp_rl.config.run_config import RunConfig, budget_source, validate
from cmdp_rl.config.threads import apply_threads
from cmdp_rl.deploy.average import ParameterAverage, deployed
from cmdp_rl.deploy.final_policy import FinalPolicy
from cmdp_rl.deploy.mixture import IterateSnapshots
from cmdp_rl.envs import check_env, make_env, make_eval_env
from cmdp_rl.policies import make_agent
from cmdp_rl.population.kernel import PopulationAgent, StackedBackend, population_env
from cmdp_rl.population.spec import Population, label, stacked, unbatched, unbatched_head
from cmdp_rl.report.metrics import (
    MetricsLogger,
    columns,
    constraint_name,
    read_metrics,
    spread,
    training_episodes,
    wandb_for,
)
from cmdp_rl.report.safety_metrics import cost_rate, load_reference, normalized_scores
from cmdp_rl.report.summary import summary_lines
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.rollout.normalization import make_normalizers
from cmdp_rl.run.checkpoint import CheckpointError, save_checkpoint
from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET, MODES, both_modes, evaluate, evaluate_members, mode_name
from cmdp_rl.run.loop import Members, contract_options, train_iterations
from cmdp_rl.run.migrations import migrate, population_from_stacked
from cmdp_rl.run.ownership import acquire, owned, release
from cmdp_rl.run.progress import Progress
from cmdp_rl.run.resume import load_resume_state
from cmdp_rl.run.rng import load_rng_state, rng_state, seed_everything
from cmdp_rl.run.rundir import (
    AGENTS_DIR,
    CHECKPOINT,
    CONFIG,
    EVAL,
    METRICS,
    POPULATION_CHECKPOINT,
    POPULATION_CONFIG,
    POPULATION_SUMMARY,
    RUN_INFO,
    TENSORBOARD,
    RunDirError,
    ensure_writable,
    write_run_info,
)


def _run_dir(cfg: RunConfig, out_dir: str | Path | None) -> Path:
    if cfg.resume is None:
        if out_dir is None:
            raise ValueError("train: out_dir is required for a new run")
        return Path(out_dir)
    if out_dir is not None and Path(out_dir).resolve() != Path(cfg.resume).resolve():
        raise ValueError(f"train: a resumed run writes to its own directory {cfg.resume}, not {out_dir}")
    return Path(cfg.resume)


# The env contract's check before training (envs/contract.py): steps per env, on envs of its own.
CONTRACT_STEPS = 100
CONTRACT_ENVS = 2


def check_env_contract(cfg: RunConfig) -> None:
    """Step a small env of the run's env config briefly and stop at the first breach of the CMDP
    contract (:class:`~cmdp_rl.envs.EnvContractError`, one line). A separate env, so the training
    env's random streams (and the run's numbers) are those of a run without the check."""
    env_cfg = cfg.env
    if getattr(env_cfg, "vector", None) == "async":  # the check reads each env's raw info: in this process
        env_cfg = dataclasses.replace(env_cfg, vector="sync")
    probe = make_env(env_cfg, num_envs=min(CONTRACT_ENVS, cfg.env.num_envs), device=cfg.device)
    try:
        env_id, allow_negative_cost = contract_options(cfg.env)
        check_env(probe, steps=CONTRACT_STEPS, seed=cfg.seed, allow_negative_cost=allow_negative_cost, env_id=env_id)
    finally:
        probe.close()


def check_env_contracts(*cfgs: RunConfig) -> None:
    """:func:`check_env_contract` once per distinct env config of the members (a run has one)."""
    checked: list[Any] = []
    for cfg in cfgs:
        if cfg.env not in checked:
            check_env_contract(cfg)
            checked.append(cfg.env)


def complete_result(
    result: dict[str, Any],
    cfg: RunConfig,
    steps: int,
    train_time: float,
    cost_totals: list[float],
    names: tuple[str, ...],
    reference: Any,
    average: ParameterAverage | IterateSnapshots | None = None,
) -> None:
    """Add to an evaluation's ``result`` what ``eval.json`` records of the run: budget, steps, train
    time, threads, the deployed policy (``final_policy``, the run's ``deploy.policy``, and how many iterations
    ``average`` holds), cost rates and normalised scores per constraint, the reference."""
    result.update(
        {
            "cost_limit": cfg.algo.cost_limit,
            "steps": steps,
            "train_time_s": train_time,
            "torch_threads": torch.get_num_threads(),
            "final_policy": cfg.deploy.policy,
            "averaged_iterations": None if average is None else average.count,
        }
    )
    if isinstance(average, IterateSnapshots):  # the mixture's members, and their weights if chosen
        result.update(average.result_keys(cfg.deploy.weights))
    k = len(names)
    limits = per_constraint(cfg.algo.cost_limit, "algo.cost_limit", names)
    eval_costs = [result[constraint_name("episode_cost", c, k)] for c in names]
    rates = [cost_rate(total, steps) for total in cost_totals]
    per_cost = {"cost_rate": rates, **normalized_scores(result["episode_return"], eval_costs, rates, limits, reference)}
    if k > 1:  # one budget per constraint, as cost_limit/<cost>
        del result["cost_limit"]
        per_cost = {"cost_limit": limits, **per_cost}
    result.update(spread(per_cost, names))
    result["reference"] = None if reference is None else dataclasses.asdict(reference)


def run_config(cfg: RunConfig) -> dict[str, Any]:
    """A run's ``config.yaml``: trusting a checkpoint or replacing a directory is one command's word,
    not the run's."""
    return dataclasses.asdict(dataclasses.replace(cfg, resume=None, overwrite=False, trust_checkpoint=False))


def open_run(
    out: Path,
    cfg: RunConfig,
    stats: tuple[str, ...],
    names: tuple[str, ...],
    state: dict | None,
    echo: Callable[[str], None],
    run_info: Path | None = None,
) -> tuple[MetricsLogger, dict[str, Any]]:
    """A run directory's files before its first iteration: the metrics logger (continuing
    ``metrics.csv`` after a resume's checkpoint), ``config.yaml`` and ``run_info.json`` (copied from
    ``run_info``, another member's, when given); the logger and the config as written. A
    ``metrics.csv`` a resume cannot continue is a :class:`CheckpointError`, before anything is written."""
    try:
        logger = MetricsLogger(
            out / METRICS,
            columns(stats, names),
            cfg.log_interval,
            echo,
            resume_iteration=None if state is None else state["iteration"],
            tensorboard_dir=out / TENSORBOARD if cfg.logger.name == "tensorboard" else None,
            resume_step=None if state is None else state["step"],
            wandb=wandb_for(cfg, out),
        )
    except ValueError as exc:
        raise CheckpointError(f"resume: {exc}") from exc
    saved = run_config(cfg)
    (out / CONFIG).write_text(yaml.safe_dump(saved, sort_keys=False))
    if run_info is not None and state is None:  # the same provenance (git calls): copied
        shutil.copyfile(run_info, out / RUN_INFO)
    else:
        write_run_info(out, resumed_from=None if state is None else state["iteration"])
    return logger, saved


def open_runs(
    dirs: Sequence[Path],
    cfgs: Sequence[RunConfig],
    stats: tuple[str, ...],
    names: tuple[str, ...],
    state: dict | None,
    echo: Callable[[str], None],
) -> tuple[list[MetricsLogger], list[dict[str, Any]]]:
    """:func:`open_run` for each member's directory (a run has one), each checked writable first;
    the first writes ``run_info.json`` and the others copy it (one process, one provenance)."""
    opened = []
    for d, c in zip(dirs, cfgs):
        ensure_writable(d)
        opened.append(open_run(d, c, stats, names, state, echo, None if d == dirs[0] else dirs[0] / RUN_INFO))
    return [logger for logger, _ in opened], [saved for _, saved in opened]


def restore(state: dict[str, Any], algos: Sequence[Any], collector: Collector) -> None:
    """A resume's checkpoint into each member's algorithm (from its entry) and into the collector."""
    for algo, entry in zip(algos, state["members"]):
        algo.load_state_dict(entry["algo_state"])
    collector.load_state_dict(state["collector"])


def write_result(out: Path, result: dict[str, Any], cfg: RunConfig, *args: Any) -> None:
    """:func:`complete_result` (``args`` are its after ``cfg``), then the run's ``eval.json``."""
    complete_result(result, cfg, *args)
    result["training_episodes"] = training_episodes(read_metrics(out / METRICS))
    (out / EVAL).write_text(json.dumps(result, indent=2))


def member_entry(run_cfg: dict[str, Any], algo: Any, final: FinalPolicy | None = None) -> dict[str, Any]:
    """A member's entry of a checkpoint: its config, its algorithm's ``state_dict`` (networks,
    optimisers, its own state) and what it deploys (``final``'s state)."""
    return {**(final.state_dict() if final else {}), "config": run_cfg, "algo_state": algo.state_dict()}


def checkpoint_state(
    cfg: RunConfig, iteration: int, step: int, time_s: float, members: list[dict], collector: Any, rng: Any, **more: Any
) -> dict[str, Any]:
    """A checkpoint (format 4, docs/checkpoints.md), a run's or a population's: what its members share
    (the iteration, each member's env ``step``s, the training time, the ``collector``'s state and the
    random state ``rng``), their entries (:func:`member_entry`) and ``more`` (a population's costs)."""
    shared = {"algo": cfg.algo.name, "policy": cfg.policy.name, "iteration": iteration, "step": step}
    return {**shared, "time_s": time_s, "collector": collector, "rng": rng, "members": members, **more}


def build_run(cfg: RunConfig) -> tuple[Any, Any, Any]:
    """A run's env, agent and algorithm, under its seed (a population builds each agent so)."""
    seed_everything(cfg.seed)
    cut_at = cfg.algo.cost_limit if cfg.early_terminate else None  # the early-terminated MDP's budget
    env = make_env(cfg.env, device=cfg.device, algo=cfg.algo, cut_at=cut_at)
    agent = make_agent(cfg.policy, env, make_normalizers(cfg, env), algo=cfg.algo)
    return env, agent, make_algo(cfg.algo, agent)


def evaluate_run(cfg: RunConfig, agent: Any) -> dict[str, Any]:
    """A run's final evaluation of ``agent`` in both modes (:func:`~cmdp_rl.run.evaluation.both_modes`):
    ``eval_episodes`` episodes on min(eval_episodes, num_envs) envs of its own, seeded with the run's
    evaluation seed, for the mean action and for sampled actions."""

    def one_mode(deterministic: bool) -> dict[str, Any]:
        eval_env = make_eval_env(
            cfg.env, num_envs=min(cfg.eval_episodes, cfg.env.num_envs), device=cfg.device, algo=cfg.algo
        )
        try:
            return evaluate(
                agent,
                eval_env,
                cfg.eval_episodes,
                deterministic,
                seed=cfg.seed + EVAL_SEED_OFFSET,
                termination_metric=cfg.env.termination_metric,  # what the env says termination means
                cost_limit=cfg.algo.cost_limit,
            )
        finally:
            eval_env.close()

    return both_modes(one_mode, cfg.eval_deterministic)


def train(
    cfg: RunConfig | Population, out_dir: str | Path | None = None, echo: Callable[[str], None] = print
) -> dict[str, Any]:
    """Train as ``cfg`` says, writing ``config.yaml``, ``run_info.json``, ``metrics.csv``,
    ``checkpoint.pt`` and ``eval.json`` under ``out_dir`` (see ``cmdp_rl/run/rundir.py``). Returns the
    evaluation summary. Same config and seed, same numbers (on the same machine and versions).

    With ``cfg.resume`` set to a run directory, continue that run from its last checkpoint, in that
    directory (``out_dir`` may be omitted). Its ``metrics.csv`` keeps the rows up to the
    checkpoint and continues after them; the run ends with the numbers it would have reached
    uninterrupted (see ``cmdp_rl/run/resume.py``).

    A :class:`~cmdp_rl.population.spec.Population` (``population.population(raw)``, or
    ``resume.resume_population(out_dir)`` to continue one) trains its P agents in this process, each
    into a run directory ``out_dir/agents/<k>_<values>/`` as its single run writes one, and returns
    the summary written to ``population.json`` (docs/population.md). Both go through one body,
    :func:`_train`: a run on :class:`OneAgent`, P agents on :class:`Stacked` where population/'s
    kernel covers them, else one run after another.
    """
    if isinstance(cfg, Population):
        if out_dir is None:
            raise ValueError("train: out_dir is required for a population")
        return _train_population(cfg, Path(out_dir), echo)
    validate(cfg)
    out = _run_dir(cfg, out_dir)
    state = load_resume_state(cfg) if cfg.resume is not None else None
    apply_threads(cfg)
    check_env_contracts(cfg)  # before seeding: whatever randomness it uses, the run's is untouched
    env, agent, algo = build_run(cfg)
    # The budgets, one per cost (a list of the wrong length stops the run here, before any output).
    per_constraint(cfg.algo.cost_limit, "algo.cost_limit", env.cost_names)
    # After the resume and config checks (a mistyped resume path or a wrong-length budget is
    # reported, no directory created), before any training: the directory is this run's alone
    # (a new run refuses one that holds a run, unless overwrite) for as long as it trains.
    try:
        acquire(out, new_run=state is None, overwrite=cfg.overwrite)
    except RunDirError:
        env.close()
        raise
    try:
        return _train([cfg], out, [out], state, OneAgent(cfg, env, agent, algo), echo)[2][0]
    finally:
        release(out)


class OneAgent:
    """The one-agent kernel of a run (P = 1): its own networks and torch's Adam (``algo.update``), its
    collector's seed and warm-up, reward and observation scaling; the global random state."""

    def __init__(self, cfg: RunConfig, env: Any, agent: Any, algo: Any) -> None:
        self.env, self.agents, self.algos = env, [agent], [algo]
        # An off-policy algorithm's options may ask for uniformly random actions during its warm-up.
        self.collector = Collector(
            env, agent, cfg.rollout_steps, seed=cfg.seed, uniform_steps=cfg.algo.uniform_action_steps
        )
        self.per_iter = cfg.rollout_steps * env.num_envs

    def restore(self, state: dict[str, Any], run_cfgs: list[dict]) -> dict[str, Any]:
        state = migrate(state, self.agents[0])  # an older format's layout (a trusted file) in the current one
        restore(state, self.algos, self.collector)
        load_rng_state(state["rng"])
        return state

    def update(self, batch: Any) -> list[dict[str, Any]]:
        normalizers = self.agents[0].normalizers
        normalizers.scale_batch(batch)  # reward/cost scaling, if on (episode sums stay raw)
        stats = self.algos[0].update(batch)
        normalizers.update_observation_stats(batch)  # after the update: see normalization.py
        return [stats]

    def cost_totals(self, batch: Any = None) -> list[list[float]]:
        return [self.collector.total_costs]

    def rng(self) -> dict[str, Any]:
        return rng_state()


class Stacked:
    """P agents on population/'s stacked kernel: each agent's networks and algorithm state as its
    single run builds them, under its seed, and the generator it then has (where its single run's
    action samples and permutations start); their envs, acting and update as one."""

    def __init__(self, cfgs: list[RunConfig], device: torch.device) -> None:
        self.agents, self.algos, self.generators = [], [], []
        for c in cfgs:
            probe, agent, algo = build_run(c)
            probe.close()
            self.agents.append(agent)
            self.algos.append(algo)
            g = torch.Generator(device=device)
            g.set_state(torch.get_rng_state() if device.type == "cpu" else torch.cuda.get_rng_state(device))
            self.generators.append(g)
        cfg, self.P = cfgs[0], len(cfgs)
        self.env = population_env(cfgs, cfg.env.num_envs, [c.seed for c in cfgs], device)
        self.agent = PopulationAgent(self.agents, self.generators, device)
        self.backend = StackedBackend(self.agent, self.algos, stacked(cfg.algo.name, getattr(cfg.algo, "base", None)))
        self.update = self.backend.update
        self.collector = Collector(self.env, self.agent, cfg.rollout_steps, seed=None)
        self.per_iter = cfg.rollout_steps * cfg.env.num_envs  # steps per agent
        self.costs = torch.zeros(self.P, len(self.env.cost_names), dtype=torch.float64)  # each agent's so far

    def restore(self, state: dict[str, Any], run_cfgs: list[dict]) -> dict[str, Any]:
        if "members" not in state:  # the stacked layout of earlier populations
            fresh = [member_entry(r, a) for r, a in zip(run_cfgs, self.algos)]
            modules = {"actor": self.agents[0].actor, "critics": self.agents[0].critics}
            state = population_from_stacked(state, fresh, modules)
        restore(state, self.algos, self.collector)  # each agent as its run resumes
        self.backend.transfer(to_agents=False)
        for g, s in zip(self.generators, state["rng"]["generators"]):
            g.set_state(s)
        # a list of P before K costs
        self.costs = torch.as_tensor(state["costs"], dtype=torch.float64).view(self.P, len(self.env.cost_names))
        return state

    def cost_totals(self, batch: Any = None) -> list[list[float]]:
        """Each agent's costs so far, ``batch``'s included."""
        if batch is not None:
            costs = batch.get((keys.NEXT, keys.COST)).reshape(self.P, -1, self.costs.shape[1]).sum(1)
            self.costs = self.costs + costs.to(self.costs)
        return self.costs.tolist()

    def rng(self) -> dict[str, Any]:
        return {"generators": [g.get_state() for g in self.generators]}

    def evaluate(self, cfgs: list[RunConfig], device: torch.device) -> list[dict[str, Any]]:
        """Each agent's single-run evaluation in both modes (``evaluation.both_modes``), side by side."""
        self.backend.copy_actors(to_modules=False)  # the deployed actors (an average) into the stacked rows
        per_mode = {name: self._evaluate_mode(cfgs, device, det) for name, det in MODES.items()}
        head = mode_name(cfgs[0].eval_deterministic)
        return [{**per_mode[head][k], "modes": {n: r[k] for n, r in per_mode.items()}} for k in range(len(cfgs))]

    def _evaluate_mode(self, cfgs: list[RunConfig], device: torch.device, deterministic: bool) -> list[dict[str, Any]]:
        """min(eval_episodes, num_envs) envs per agent, seeded with its evaluation seed, which also seeds its
        action samples."""
        cfg = cfgs[0]
        seeds = [c.seed + EVAL_SEED_OFFSET for c in cfgs]
        eval_env = population_env(cfgs, min(cfg.eval_episodes, cfg.env.num_envs), seeds, device, evaluation=True)
        self.agent.generators = [torch.Generator(device=device).manual_seed(s) for s in seeds]
        limits = [c.algo.cost_limit for c in cfgs]
        try:
            return evaluate_members(
                self.agent, eval_env, cfg.eval_episodes, deterministic, limits, cfg.env.termination_metric
            )
        finally:
            self.agent.generators = self.generators
            eval_env.close()


def _train(
    cfgs: list[RunConfig], out: Path, dirs: list[Path], state: dict | None, kernel: Any, echo: Callable[[str], None]
) -> tuple[int, float, list[dict[str, Any]]]:
    """Train the members ``cfgs`` on ``kernel`` (a run's :class:`OneAgent`, or :class:`Stacked`), each
    into its directory of ``dirs``, checkpointing into ``out``'s; returns each member's steps, the
    training time and each member's evaluation."""
    cfg, P, names, collector = cfgs[0], len(cfgs), kernel.env.cost_names, kernel.collector
    run = isinstance(kernel, OneAgent)  # else a population (of any P) with its own lines and checkpoint
    try:  # the last check a resume can fail: nothing is written before it
        loggers, run_cfgs = open_runs(dirs, cfgs, kernel.algos[0].stats, names, state, echo if run else lambda s: None)
    except CheckpointError:
        kernel.env.close()
        raise
    first, elapsed = 1, 0.0
    if state is not None:
        state = kernel.restore(state, run_cfgs)
        first, elapsed = state["iteration"] + 1, state["time_s"]
    iterations = math.ceil(cfg.total_steps / kernel.per_iter)
    start = time.perf_counter() - elapsed
    # What each member deploys (deploy.policy), kept on its single-run agent (final_policy.py).
    finals = [FinalPolicy(c, iterations, e) for c, e in zip(cfgs, state["members"] if state else [None] * P)]
    reference, warnings = load_reference(cfg) if run else (None, [])
    for warning in warnings:
        echo(f"warning: {warning}")
    cannot_resume: list[str] = []
    written: dict[int, list[dict[str, Any]]] = {}  # the entries of the last checkpoint, by iteration

    def entries(it: int) -> list[dict[str, Any]]:
        if it not in written:  # the final one is the last checkpoint's: built once
            if not run:  # the stacked rows into each agent's own objects (its state_dict its single run's)
                kernel.backend.transfer(to_agents=True)
            written.clear()
            written[it] = [member_entry(r, a, f) for r, a, f in zip(run_cfgs, kernel.algos, finals)]
        return written[it]

    def checkpoint(it: int, time_s: float) -> None:
        try:
            rollout = collector.state_dict()
        except NotImplementedError as exc:  # an env that cannot save itself: evaluable, not resumable
            rollout = None
            if not cannot_resume:
                cannot_resume.append(str(exc))
                say(f"warning: {exc}; checkpoints of this run can be evaluated but not resumed")
        steps = collector.total_steps // P
        more = {} if run else {"costs": kernel.costs}
        save_checkpoint(
            out / CHECKPOINT, checkpoint_state(cfg, it, steps, time_s, entries(it), rollout, kernel.rng(), **more)
        )
        if not run:
            (out / POPULATION_CHECKPOINT).unlink(missing_ok=True)  # an older population's, now superseded

    progress, report = None, None
    if run:
        if state is not None:
            echo(f"resuming {out} from iteration {state['iteration']} (step {collector.total_steps:,})")
        shape = f"{kernel.per_iter} steps ({cfg.rollout_steps} per env"
        described = cfg.algo.describe_update()
        if described:
            shape += f"; {described}"
        backend = getattr(cfg.env, "backend", None)  # only envs with several implementations have one
        where = f"{backend}, " if backend else ""
        cut = ", training episodes end past it (early_terminate)" if cfg.early_terminate else ""
        echo(
            f"training {cfg.algo.name} on {cfg.env.name} ({where}{kernel.env.num_envs} envs): "
            f"{iterations} iterations of {shape}), cost limit {cfg.algo.cost_limit} ({budget_source(cfg)}){cut}, "
            f"outputs in {out}"
        )
        progress = Progress(iterations * kernel.per_iter, (first - 1) * kernel.per_iter, echo)  # a bar on a terminal
        loggers[0].echo = progress.row_echo
    else:
        if state is not None:
            echo(f"resuming population {out} from iteration {state['iteration']}")
        echo(
            f"training a population of {P} {cfg.algo.name} agents on {cfg.env.name} ({cfg.env.num_envs} envs each): "
            f"{iterations} iterations of {kernel.per_iter} steps per agent ({cfg.algo.describe_update()}), outputs in {out}"
        )

        def report(it: int, rows: list[dict[str, Any]], dt: float) -> None:
            if it % cfg.log_interval == 0 or it == first or it == iterations:
                mean = [
                    torch.tensor([r[k] for r in rows], dtype=torch.float64).nanmean().item()
                    for k in ("episode_return", constraint_name("episode_cost", names[0], len(names)))
                ]
                echo(
                    f"iteration {it}/{iterations}: {P} agents, {P * kernel.per_iter / dt:,.0f} steps/s summed, "
                    f"mean episode return {mean[0]:.3f}, cost {mean[1]:.3f}"
                )

    say = progress.write if progress is not None else echo

    def update(batch: Any, it: int) -> list[dict[str, Any]]:
        stats = kernel.update(batch)
        if any(f.wants(it) for f in finals):  # the actors as their members' modules hold them
            if not run:
                kernel.backend.copy_actors(to_modules=True)
            for k, (f, a) in enumerate(zip(finals, kernel.agents)):
                f.after_update(a, it, names, echo if run else lambda line, k=k: echo(f"agent {k}: {line}"))
        return stats

    members = Members(
        cfgs, loggers, collector, update, kernel.cost_totals, checkpoint, out / CHECKPOINT, reference, report
    )
    train_time = train_iterations(members, first, iterations, start, progress)
    steps = collector.total_steps // P
    if first > iterations:
        echo(f"{out}: training had already finished at iteration {first - 1}; evaluating")

    final_entries = [] if run else entries(iterations)  # the last iterates, before the deployed policies
    for f, a in zip(finals, kernel.agents):
        f.deploy(a)
    if run or cfg.deploy.policy == "mixture":  # each member's policy as its run evaluates it
        results = [evaluate_run(c, a) for c, a in zip(cfgs, kernel.agents)]
    else:
        results = kernel.evaluate(cfgs, torch.device(cfg.device))
    totals = kernel.cost_totals()
    for k, (d, c, result, f) in enumerate(zip(dirs, cfgs, results, finals)):
        if not run:  # the agent's entry of the last checkpoint as its own (it evaluates; the population resumes)
            save_checkpoint(
                d / CHECKPOINT, checkpoint_state(c, iterations, steps, train_time, [final_entries[k]], None, None)
            )
        write_result(d, result, c, steps, train_time, totals[k], names, reference, f.kept)
        loggers[k].finish(result)  # the summary beside the metrics (logger=wandb)
    if run:
        header = f"done: {cfg.algo.name} {collector.total_steps:,} steps in {train_time:.1f}s; {deployed(results[0])}"
        for line in summary_lines(results[0], cfg.env, cfg.algo.cost_limit, header=header, cost_names=names):
            echo(line)
    return steps, train_time, results


# --- P agents ------------------------------------------------------------------------------------


def agent_dir_name(k: int, overrides: dict[str, Any]) -> str:
    return f"{k:03d}_{label(overrides)}".replace("/", "_").replace(" ", "")


def _train_population(pop: Population, out: Path, echo: Callable[[str], None]) -> dict[str, Any]:
    """:func:`train` of P agents: the stacked kernel where population/ covers them, else each agent's
    run one after another in this process (a resume continues each from its own checkpoint)."""
    cfgs, P = pop.cfgs, len(pop.cfgs)
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
            kernel = Stacked(cfgs, torch.device(cfgs[0].device))
            steps, train_time, results = _train(cfgs, out, dirs, pop.state, kernel, echo)
        else:  # the numbers of separate runs, and none of the batched program's speed
            echo(f"population: {why}; its {P} agents train one after another, each as its single run, outputs in {out}")
            results = []
            for k, (d, c) in enumerate(zip(dirs, cfgs)):
                if pop.resume:  # from the agent's checkpoint (a finished one is evaluated again), or anew
                    resumed = (d / CHECKPOINT).is_file()
                    c = dataclasses.replace(c, resume=str(d) if resumed else None, overwrite=not resumed)
                echo(f"agent {k + 1}/{P} ({label(pop.overrides[k])}):")
                results.append(train(c, d, echo=echo))
            steps, train_time = results[-1]["steps"], sum(r["train_time_s"] for r in results)
        runs = [
            {"dir": str(d.relative_to(out)), "values": ov, **{k: r.get(k) for k in ("episode_return", "episode_cost")}}
            for d, ov, r in zip(dirs, pop.overrides, results)
        ]
        summary = {
            "agents": P,
            "algo": cfgs[0].algo.name,
            **({"envs_per_agent": cfgs[0].env.num_envs, "iterations": _iterations(cfgs[0])} if why is None else {}),
            "steps_per_agent": steps,
            "steps_summed": steps * P,
            "train_time_s": train_time,
            "summed_steps_per_s": steps * P / train_time,
            "wall_time_s": time.perf_counter() - start,
            "device": str(cfgs[0].device),
            "torch_threads": torch.get_num_threads(),
            "runs": runs,
        }
        (out / POPULATION_SUMMARY).write_text(json.dumps(summary, indent=2))
        echo(
            f"done: {P} agents x {steps:,} steps in {train_time:.1f}s ({summary['summed_steps_per_s']:,.0f} steps/s "
            f"summed); runs in {out / AGENTS_DIR}, summary {out / POPULATION_SUMMARY}"
        )
    return summary


def _iterations(cfg: RunConfig) -> int:
    return math.ceil(cfg.total_steps / (cfg.rollout_steps * cfg.env.num_envs))
