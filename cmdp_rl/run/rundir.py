"""A run directory (what it holds: ``config/saved.py``): claiming it writable, its provenance, and reading a trained
policy back from it."""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
import sys
import traceback
from importlib import metadata
from pathlib import Path
from typing import Any, NamedTuple

from cmdp_rl.config.run_config import ConfigError, RunConfig, load_config
from cmdp_rl.config.saved import (
    AGENTS_DIR,
    CHECKPOINT,
    CONFIG,
    ERROR,
    POPULATION_CONFIG,
    RUN_INFO,
    read_yaml,
)
from cmdp_rl.deploy.final_policy import deploy_saved
from cmdp_rl.deploy.policy import DeployedPolicy
from cmdp_rl.envs import VecEnv, make_eval_env
from cmdp_rl.policies import Agent, make_agent
from cmdp_rl.rollout.normalization import Normalizers
from cmdp_rl.run.checkpoint import CheckpointError, load_checkpoint
from cmdp_rl.run.migrations import member, migrate, saved_config_defaults


class RunDirError(ConfigError):
    """The run directory cannot be created or written (one line, exit status 2 in ``train.py``)."""


def ensure_writable(run_dir: str | Path) -> Path:
    """Create ``run_dir`` (and its parents) if needed and check that a file can be written in it,
    so that a run whose outputs cannot be kept stops before training, not at its first write."""
    path = Path(run_dir)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write_check_{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise RunDirError(
            f"run directory {path} cannot be created or written: {exc.strerror or type(exc).__name__}"
        ) from None
    return path


LIBRARIES = ("torch", "torchrl", "tensordict", "gymnasium", "numpy", "hydra-core")


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(
            ["git", *args], cwd=Path(__file__).resolve().parent, capture_output=True, text=True, timeout=10
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def _version() -> str | None:
    """The installed package's version (pyproject.toml's); None where cmdp_rl runs from a checkout not installed."""
    try:
        return metadata.version("cmdp_rl")
    except metadata.PackageNotFoundError:
        return None


def provenance() -> dict[str, Any]:
    """What produced a run: the package version, the git commit of its source (and whether the
    working tree had uncommitted changes), library versions, Python, platform and command line."""
    # Only the checkout the package's source lives in (not, say, a repo that holds a virtualenv).
    top = _git("rev-parse", "--show-toplevel")
    here = Path(__file__).resolve().parents[1]  # the cmdp_rl package directory
    commit = _git("rev-parse", "HEAD") if top and (Path(top) / here.name).resolve() == here else None
    status = _git("status", "--porcelain") if commit else None
    libs = {}
    for lib in LIBRARIES:
        try:
            libs[lib] = metadata.version(lib)
        except metadata.PackageNotFoundError:
            libs[lib] = None
    return {
        "version": _version(),
        "git_commit": commit,  # None: not run from a git checkout
        "git_dirty": None if status is None else bool(status),
        "libraries": libs,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "command": [sys.executable, *sys.argv],
        "time": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
    }


def write_run_info(run_dir: str | Path, resumed_from: int | None = None) -> Path:
    """Write ``run_info.json`` for a new run, or add a resume (from the checkpoint of iteration
    ``resumed_from``) to its ``resumes`` list: a resume may run other code than the start did."""
    path = Path(run_dir) / RUN_INFO
    now = provenance()
    if resumed_from is None or not path.is_file():
        info = {"package": "cmdp_rl", **now, "resumes": []}
    else:
        info = json.loads(path.read_text())
        info.setdefault("resumes", []).append({"from_iteration": resumed_from, **now})
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(info, indent=2))
    os.replace(tmp, path)
    return path


def checkpoint_path(run_dir: str | Path, what: str = "run") -> Path:
    """The run's checkpoint; a clear error if the directory or the checkpoint is missing."""
    run = Path(run_dir)
    if not run.is_dir():
        raise CheckpointError(f"{what}: no run directory at {run}")
    if (run / POPULATION_CONFIG).is_file():
        raise CheckpointError(f"{what}: {run} is a population; its agents' runs are under {run / AGENTS_DIR}")
    ckpt = run / CHECKPOINT
    if not ckpt.is_file():
        raise CheckpointError(f"{what}: no {CHECKPOINT} in {run} (did the run stop before its first checkpoint?)")
    return ckpt


def saved_config(run_dir: str | Path, what: str = "run", trust: bool = False) -> dict[str, Any]:
    """The run's own config as a plain mapping: its ``config.yaml`` (read with YAML's safe loader),
    else the one in its checkpoint (``trust``: see :func:`~cmdp_rl.run.checkpoint.load_checkpoint`)."""
    ckpt = checkpoint_path(run_dir, what)
    cfg_path = Path(run_dir) / CONFIG
    if cfg_path.is_file():
        return saved_config_defaults(read_yaml(cfg_path, what))
    return saved_config_defaults(member(load_checkpoint(ckpt, trust=trust))["config"])


def run_config(run_dir: str | Path, what: str = "run", trust: bool = False) -> RunConfig:
    saved = saved_config(run_dir, what, trust)
    try:
        return load_config({**saved, "resume": None})
    except ConfigError as exc:
        raise CheckpointError(f"{what}: the config of {run_dir} is not valid here: {exc}") from exc


class Trained(NamedTuple):
    cfg: RunConfig
    env: VecEnv
    agent: Agent
    iteration: int
    step: int


def load_trained(
    run_dir: str | Path, checkpoint: str | Path | None = None, num_envs: int = 1, trust: bool = False
) -> Trained:
    """Rebuild a run's env (``num_envs`` of them) and agent, and load its checkpoint (or
    ``checkpoint``) into them. A checkpoint written by another algorithm or policy than the run's
    config names, or one whose networks do not fit it, raises :class:`CheckpointError`; one of an
    older format, :class:`~cmdp_rl.run.checkpoint.UnsafeCheckpointError` unless ``trust``.
    """
    cfg = run_config(run_dir, "evaluate", trust)
    ckpt = Path(checkpoint) if checkpoint is not None else checkpoint_path(run_dir, "evaluate")
    state = load_checkpoint(ckpt, algo=cfg.algo.name, policy=cfg.policy.name, trust=trust)
    env = make_eval_env(cfg.env, num_envs=num_envs, algo=cfg.algo)
    # Normalizer buffers are shaped by the training envs (running discounted sums per env).
    norm = Normalizers.from_config(cfg.normalize, env.obs_dim, cfg.env.num_envs, cfg.algo.gamma, cfg.algo.cost_gamma)
    agent = make_agent(cfg.policy, env, norm, algo=cfg.algo)  # the algorithm's networks, no algorithm
    try:  # every algorithm keeps its agent's state under "networks" (docs/architecture.md)
        entry = member(migrate(state, agent))
        agent.load_state_dict(entry["algo_state"]["networks"])
    except (KeyError, RuntimeError) as exc:
        env.close()
        raise CheckpointError(f"evaluate: {ckpt} does not fit the config of {run_dir} ({exc})") from exc
    try:  # the policy the run deployed: the last iterate, its average or its mixture (deploy/)
        deploy_saved(cfg, entry, agent)
    except ValueError as exc:
        env.close()
        raise CheckpointError(f"evaluate: {ckpt}: {exc} ({run_dir})") from exc
    return Trained(cfg, env, agent, int(state["iteration"]), int(state["step"]))


def load(run_dir: str | Path, checkpoint: str | Path | None = None, trust: bool = False) -> DeployedPolicy:
    """The policy the run in ``run_dir`` deployed (its last checkpoint's, or ``checkpoint``'s), ready to
    act: ``cmdp_rl.load(run_dir).predict(obs)``. Errors as :func:`load_trained`'s."""
    trained = load_trained(run_dir, checkpoint, num_envs=1, trust=trust)
    try:
        return DeployedPolicy(trained.agent, trained.env.action_space, trained.env.num_costs, trained.cfg)
    finally:
        trained.env.close()


def record_failure(out_dir: str | Path, exc: BaseException) -> None:
    """Write ``error.txt`` (exception type, message, traceback) into the run directory."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    text = f"{type(exc).__name__}: {exc}\n\n" + "".join(traceback.format_exception(exc))
    (out / ERROR).write_text(text)
