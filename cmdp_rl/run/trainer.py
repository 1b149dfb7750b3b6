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
from cmdp_rl.report.metrics import MetricsLogger, columns, constraint_name, spread, wandb_for
from cmdp_rl.report.safety_metrics import cost_rate, load_reference, normalized_scores
from cmdp_rl.report.summary import summary_lines
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.rollout.normalization import make_normalizers
from cmdp_rl.run.checkpoint import CheckpointError, save_checkpoint
from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET, evaluate
from cmdp_rl.run.loop import Members, contract_options, train_iterations
from cmdp_rl.run.migrations import migrate
from cmdp_rl.run.ownership import acquire, release
from cmdp_rl.run.progress import Progress
from cmdp_rl.run.resume import load_resume_state
from cmdp_rl.run.rng import load_rng_state, rng_state, seed_everything
from cmdp_rl.run.rundir import (
    CHECKPOINT,
    CONFIG,
    EVAL,
    METRICS,
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


# The env contract's check before training (envs/contract.py): steps per env, on this many envs
# built for it alone.
CONTRACT_STEPS = 100
CONTRACT_ENVS = 2


def check_env_contract(cfg: RunConfig) -> None:
    """Step a small env of the run's env config briefly and stop at the first breach of the CMDP
    contract (:class:`~cmdp_rl.envs.EnvContractError`, one line naming the env, index, step and
    field). A separate env, so the training env's random streams (and the run's numbers) are those
    of a run without the check."""
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
    ``metrics.csv`` after a resume's checkpoint), ``config.yaml`` and ``run_info.json`` (copied
    from ``run_info``, another run's of the same process, when given). Returns the logger and the
    run's config as written. A ``metrics.csv`` that a resume cannot continue is a
    :class:`CheckpointError`, raised before anything is written."""
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


def restore(
    state: dict[str, Any], algos: Sequence[Any], entries: Sequence[dict], collector: Collector
) -> tuple[int, float]:
    """A resume's checkpoint into each member's algorithm (from its entry: a run's is the checkpoint
    itself) and into the collector. Returns the first iteration to train and the time trained."""
    for algo, entry in zip(algos, entries):
        algo.load_state_dict(entry["algo_state"])
    collector.load_state_dict(state["collector"])
    return state["iteration"] + 1, state["time_s"]


def write_result(out: Path, result: dict[str, Any], cfg: RunConfig, *args: Any) -> None:
    """:func:`complete_result` (``args`` are its after ``cfg``), then the run's ``eval.json``."""
    complete_result(result, cfg, *args)
    (out / EVAL).write_text(json.dumps(result, indent=2))


def checkpoint_entry(run_cfg: dict[str, Any], iteration: int, step: int, time_s: float, algo: Any) -> dict[str, Any]:
    """A ``checkpoint.pt``'s run fields and the algorithm's ``state_dict`` (networks, optimisers,
    its own state); the caller adds the collector's and the random generators' state."""
    return {
        "algo": run_cfg["algo"]["name"],
        "policy": run_cfg["policy"]["name"],
        "config": run_cfg,
        "iteration": iteration,
        "step": step,
        "time_s": time_s,
        "algo_state": algo.state_dict(),
    }


def build_run(cfg: RunConfig) -> tuple[Any, Any, Any]:
    """A run's env, agent and algorithm, under its seed (a population builds each agent so)."""
    seed_everything(cfg.seed)
    cut_at = cfg.algo.cost_limit if cfg.early_terminate else None  # the early-terminated MDP's budget
    env = make_env(cfg.env, device=cfg.device, algo=cfg.algo, cut_at=cut_at)
    agent = make_agent(cfg.policy, env, make_normalizers(cfg, env), algo=cfg.algo)
    return env, agent, make_algo(cfg.algo, agent)


def evaluate_run(cfg: RunConfig, agent: Any) -> dict[str, Any]:
    """A run's final evaluation of ``agent``: ``eval_episodes`` episodes on min(eval_episodes,
    num_envs) envs of its own, seeded with the run's evaluation seed."""
    eval_env = make_eval_env(
        cfg.env, num_envs=min(cfg.eval_episodes, cfg.env.num_envs), device=cfg.device, algo=cfg.algo
    )
    try:
        return evaluate(
            agent,
            eval_env,
            cfg.eval_episodes,
            cfg.eval_deterministic,
            seed=cfg.seed + EVAL_SEED_OFFSET,
            termination_metric=cfg.env.termination_metric,  # what the env says termination means
            cost_limit=cfg.algo.cost_limit,
        )
    finally:
        eval_env.close()


def train(cfg: RunConfig, out_dir: str | Path | None = None, echo: Callable[[str], None] = print) -> dict[str, Any]:
    """Train as ``cfg`` says, writing ``config.yaml``, ``run_info.json``, ``metrics.csv``,
    ``checkpoint.pt`` and ``eval.json`` under ``out_dir`` (see ``cmdp_rl/run/rundir.py``). Returns the
    evaluation summary. Same config and seed, same numbers (on the same machine and versions).

    With ``cfg.resume`` set to a run directory, continue that run from its last checkpoint, in that
    directory (``out_dir`` may be omitted). Its ``metrics.csv`` keeps the rows up to the
    checkpoint and continues after them; the run ends with the numbers it would have reached
    uninterrupted (see ``cmdp_rl/run/resume.py``).
    """
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
        return _train(cfg, out, state, env, agent, algo, echo)
    finally:
        release(out)


def _train(
    cfg: RunConfig,
    out: Path,
    state: dict | None,
    env: Any,
    agent: Any,
    algo: Any,
    echo: Callable[[str], None],
) -> dict[str, Any]:
    """The rest of :func:`train`, in a run directory this process holds."""
    names = env.cost_names
    # An off-policy algorithm's options may ask for uniformly random actions during its warm-up.
    collector = Collector(env, agent, cfg.rollout_steps, seed=cfg.seed, uniform_steps=cfg.algo.uniform_action_steps)
    try:  # the last check a resume can fail: nothing is written before it
        (logger,), (run_cfg,) = open_runs([out], [cfg], algo.stats, names, state, echo)
    except CheckpointError:
        env.close()
        raise
    first, elapsed = 1, 0.0
    if state is not None:
        state = migrate(state, agent)  # an older format's layout (a trusted file) in the current one
        first, elapsed = restore(state, [algo], [state], collector)
        load_rng_state(state["rng"])
    per_iter = cfg.rollout_steps * env.num_envs
    iterations = math.ceil(cfg.total_steps / per_iter)
    ckpt_path = out / CHECKPOINT
    start = time.perf_counter() - elapsed
    final = FinalPolicy(cfg, iterations, state)  # what the run deploys: deploy.policy

    reference, warnings = load_reference(cfg)
    for warning in warnings:
        echo(f"warning: {warning}")
    cannot_resume: list[str] = []

    def checkpoint(iteration: int, time_s: float) -> None:
        try:
            rollout = collector.state_dict()
        except NotImplementedError as exc:  # an env that cannot save itself: evaluable, not resumable
            rollout = None
            if not cannot_resume:
                cannot_resume.append(str(exc))
                progress.write(f"warning: {exc}; checkpoints of this run can be evaluated but not resumed")
        entry = checkpoint_entry(run_cfg, iteration, collector.total_steps, time_s, algo)
        save_checkpoint(ckpt_path, {**final.state_dict(), **entry, "collector": rollout, "rng": rng_state()})

    if state is not None:
        echo(f"resuming {out} from iteration {state['iteration']} (step {collector.total_steps:,})")
    shape = f"{per_iter} steps ({cfg.rollout_steps} per env"
    described = cfg.algo.describe_update()
    if described:
        shape += f"; {described}"
    backend = getattr(cfg.env, "backend", None)  # only envs with several implementations have one
    where = f"{backend}, " if backend else ""
    cut = ", training episodes end past it (early_terminate)" if cfg.early_terminate else ""
    echo(
        f"training {cfg.algo.name} on {cfg.env.name} ({where}{env.num_envs} envs): "
        f"{iterations} iterations of {shape}), cost limit {cfg.algo.cost_limit} ({budget_source(cfg)}){cut}, "
        f"outputs in {out}"
    )
    progress = Progress(iterations * per_iter, (first - 1) * per_iter, echo)  # a bar on a terminal
    logger.echo = progress.row_echo

    def update(batch: Any, it: int) -> list[dict[str, Any]]:
        agent.normalizers.scale_batch(batch)  # reward/cost scaling, if on (episode sums stay raw)
        stats = algo.update(batch)
        agent.normalizers.update_observation_stats(batch)  # after the update: see normalization.py
        final.after_update(agent, it, names, echo)
        return [stats]

    members = Members(
        [cfg],
        [logger],
        collector,
        update,
        lambda batch: [collector.total_costs],
        checkpoint,
        ckpt_path,
        reference,
    )
    train_time = train_iterations(members, first, iterations, start, progress)
    if first > iterations:
        echo(f"{out}: training had already finished at iteration {first - 1}; evaluating")

    final.deploy(agent)
    result = evaluate_run(cfg, agent)
    write_result(
        out, result, cfg, collector.total_steps, train_time, collector.total_costs, names, reference, final.kept
    )
    logger.finish(result)  # the summary beside the metrics (logger=wandb)
    header = f"done: {cfg.algo.name} {collector.total_steps:,} steps in {train_time:.1f}s; {deployed(result)}"
    for line in summary_lines(result, cfg.env, cfg.algo.cost_limit, header=header, cost_names=names):
        echo(line)
    return result
