"""Continuing a run from its directory (a population: ``population/resume.py``): which config it resumes with, and what may change.

A resumed run must end with the numbers of one never stopped, so its config is its own (``config.yaml``);
options on the resume command line apply only where they cannot change the trajectory so far or the
shape of saved state (:data:`RESUMABLE`: ``total_steps`` to extend a run, ``logger``, ...). Any other
change, and a checkpoint of another algorithm or policy, is refused before training. What a
checkpoint holds: docs/checkpoints.md.
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Any, Iterable, Mapping

from cmdp_rl.config.run_config import ConfigError, RunConfig, flatten_dict, load_config
from cmdp_rl.run.checkpoint import CheckpointError, load_checkpoint
from cmdp_rl.run.migrations import member, saved_config_defaults
from cmdp_rl.run.rundir import checkpoint_path, saved_config

# Fields a resume command line may change: none of them alters what the run has done so far or the
# shape of anything saved. Prefixes: every field under ``logger.``.
# algo.anneal_lr: the learning-rate schedule of the iterations still to come ("auto" follows total_steps, so
# extending a run stretches it).
RESUMABLE = (
    "total_steps",
    "checkpoint_every",
    "log_interval",
    "eval_episodes",
    "eval_deterministic",
    "threads",
    "resume",
    "trust_checkpoint",
    "logger.",
    "algo.anneal_lr",
)
# Config groups selected by name on a command line (``algo=ppo``); they set ``<group>.name``.
GROUPS = ("algo", "env", "policy", "logger")


def _resumable(field: str) -> bool:
    return any(field == r or (r.endswith(".") and field.startswith(r)) for r in RESUMABLE)


def resume_config(run_dir: str | Path, requested: Mapping[str, Any], explicit: Iterable[str]) -> RunConfig:
    """The config to resume ``run_dir`` with: the run's own, plus the options named in ``explicit``
    (dotted keys or group names, as on a command line) taken from ``requested``.

    Selecting another algorithm or policy than the run's raises :class:`CheckpointError`; changing
    a field outside :data:`RESUMABLE` raises :class:`ConfigError` (from :func:`check_resume_config`).
    """
    trust = bool(requested.get("trust_checkpoint")) and "trust_checkpoint" in explicit
    saved = saved_config(run_dir, "resume", trust)
    merged = resumed_raw(saved, requested, explicit, run_dir)
    try:
        cfg = load_config(merged)
    except ConfigError as exc:
        raise ConfigError(f"{exc} (resuming {run_dir})") from exc
    check_resume_config(load_config({**saved, "resume": None}), cfg)
    return cfg


def resumed_raw(
    saved: Mapping[str, Any], requested: Mapping[str, Any], explicit: Iterable[str], run_dir: str | Path
) -> dict[str, Any]:
    """A run's (or a population's) saved config with the options named in ``explicit`` taken from
    ``requested``; what a resume may change is checked by the caller (:func:`check_resume_config`)."""
    merged = copy.deepcopy(dict(saved))
    for key in explicit:
        if key == "hydra" or key.startswith("hydra."):  # Hydra's own settings, not the run's
            continue
        if key in GROUPS and isinstance(requested.get(key), Mapping):
            want, have = requested[key].get("name"), (merged.get(key) or {}).get("name")
            if want != have:
                if key in ("algo", "policy"):
                    raise CheckpointError(
                        f"resume: {run_dir} is a run of {key}={have!r}, but this command asks for {key}={want!r}"
                    )
                if key != "logger":  # another env: refused below with the field named
                    merged.setdefault(key, {})["name"] = want
                    continue
                merged[key] = dict(requested[key])  # another logger: take its whole group
            continue
        node, parts = merged, key.split(".")
        src: Any = requested
        for p in parts:
            src = src[p] if isinstance(src, Mapping) and p in src else None
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = src
    merged["resume"] = str(run_dir)
    return merged


def check_resume_config(saved: RunConfig, cfg: RunConfig) -> None:
    """Refuse to resume a run saved with ``saved`` under ``cfg`` where that would not continue it."""
    for group in ("algo", "policy"):
        have, want = getattr(saved, group).name, getattr(cfg, group).name
        if have != want:
            raise CheckpointError(f"resume: the checkpoint is of {group}={have!r}, but this run uses {group}={want!r}")
    a, b = flatten_dict(dataclasses.asdict(saved)), flatten_dict(dataclasses.asdict(cfg))
    changed = [f for f in sorted(a.keys() | b.keys()) if not _resumable(f) and a.get(f) != b.get(f)]
    if changed:
        detail = "; ".join(f"{f}: run has {a.get(f)!r}, asked {b.get(f)!r}" for f in changed)
        raise ConfigError(
            f"{changed[0]} cannot change when resuming ({detail}); only these may: "
            f"{', '.join(r.rstrip('.') for r in RESUMABLE if r != 'resume')}"
        )


def load_resume_state(cfg: RunConfig) -> dict[str, Any]:
    """The checkpoint ``cfg.resume`` names, checked against ``cfg`` (algorithm, policy, config), as
    it was written: :func:`cmdp_rl.run.migrations.migrate` brings an older format's to the current one."""
    assert cfg.resume is not None
    ckpt = checkpoint_path(cfg.resume, "resume")
    state = load_checkpoint(ckpt, algo=cfg.algo.name, policy=cfg.policy.name, trust=cfg.trust_checkpoint)
    entry = member(state)
    missing = [k for k in ("collector", "rng", "iteration") if state.get(k) is None]
    missing += [] if entry.get("algo_state") is not None else ["algo_state"]
    if missing == ["collector"]:
        raise CheckpointError(
            f"resume: {ckpt} holds no env state (env {cfg.env.name!r}, "
            f"backend {getattr(cfg.env, 'backend', None)!r}, cannot save"
            " its episodes and generators), so the run cannot continue exactly; evaluate it or start anew"
        )
    if missing:
        raise CheckpointError(f"resume: {ckpt} lacks {missing}; it cannot continue a run")
    check_resume_config(load_config({**saved_config_defaults(entry["config"]), "resume": None}), cfg)
    return state
