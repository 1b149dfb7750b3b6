"""Opening a run, new or resumed, before its first iteration: its directory, the env contract's check, its env,
agent and algorithm under its seed, its files (``config.yaml``, ``run_info.json``, the metrics logger) and a
resume's checkpoint put back into the members (:func:`open_members`, which a population's members share)."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Any, Callable, Sequence

import yaml

from cmdp_rl.algos import make_algo
from cmdp_rl.config.run_config import RunConfig
from cmdp_rl.config.saved import CONFIG, METRICS, RUN_INFO, TENSORBOARD
from cmdp_rl.deploy.final_policy import FinalPolicy
from cmdp_rl.envs import check_env, make_env
from cmdp_rl.envs.contract import contract_options
from cmdp_rl.policies import make_agent
from cmdp_rl.report.metrics import MetricsLogger, columns, wandb_for
from cmdp_rl.rollout.normalization import make_normalizers
from cmdp_rl.run.checkpoint import CheckpointError
from cmdp_rl.run.kernel import Kernel
from cmdp_rl.run.rng import seed_everything
from cmdp_rl.run.rundir import ensure_writable, write_run_info

# The env contract's check before training (envs/contract.py): steps per env, on envs of its own.
CONTRACT_STEPS = 100
CONTRACT_ENVS = 2


def run_directory(cfg: RunConfig, out_dir: str | Path | None) -> Path:
    """Where the run writes: ``out_dir`` for a new run, its own directory for a resumed one."""
    if cfg.resume is None:
        if out_dir is None:
            raise ValueError("train: out_dir is required for a new run")
        return Path(out_dir)
    if out_dir is not None and Path(out_dir).resolve() != Path(cfg.resume).resolve():
        raise ValueError(f"train: a resumed run writes to its own directory {cfg.resume}, not {out_dir}")
    return Path(cfg.resume)


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


def build_run(cfg: RunConfig) -> tuple[Any, Any, Any]:
    """A run's env, agent and algorithm, under its seed (a population builds each agent so)."""
    seed_everything(cfg.seed)
    cut_at = cfg.algo.cost_limit if cfg.early_terminate else None  # the early-terminated MDP's budget
    env = make_env(cfg.env, device=cfg.device, algo=cfg.algo, cut_at=cut_at)
    agent = make_agent(cfg.policy, env, make_normalizers(cfg, env), algo=cfg.algo)
    return env, agent, make_algo(cfg.algo, agent)


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


@dataclasses.dataclass
class Opened:
    """The members' run directories opened: their loggers, their ``config.yaml`` as written, what each deploys
    (continuing a resume's), the first iteration to train and the training time before it (a resume's)."""

    loggers: list[MetricsLogger]
    saved: list[dict[str, Any]]
    finals: list[FinalPolicy]
    first: int = 1
    elapsed: float = 0.0


def open_members(
    cfgs: Sequence[RunConfig],
    dirs: Sequence[Path],
    kernel: Kernel,
    state: dict | None,
    iterations: int,
    echo: Callable[[str], None],
) -> Opened:
    """Each member's directory of ``dirs`` opened (:func:`open_runs`; ``echo`` prints its logger's rows) and a
    resume's checkpoint ``state`` put back into ``kernel``. The last check a resume can fail (a ``metrics.csv`` it
    cannot continue) closes the env: nothing is written before it."""
    try:
        loggers, saved = open_runs(dirs, cfgs, kernel.algos[0].stats, kernel.env.cost_names, state, echo)
    except CheckpointError:
        kernel.env.close()
        raise
    first, elapsed = 1, 0.0
    if state is not None:
        state = kernel.restore(state, saved)
        first, elapsed = state["iteration"] + 1, state["time_s"]
    # What each member deploys (deploy.policy), kept on its single-run agent (final_policy.py).
    entries = state["members"] if state else [None] * len(cfgs)
    finals = [FinalPolicy(c, iterations, e) for c, e in zip(cfgs, entries)]
    return Opened(loggers, saved, finals, first, elapsed)
