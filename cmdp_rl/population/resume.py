"""Continuing a population (``train.py resume=<population dir>``): its own config, the options a run's resume may
change, and its checkpoint in the current layout, as ``run/resume.py`` continues a run."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping

from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.config.saved import CHECKPOINT, POPULATION_CHECKPOINT, POPULATION_CONFIG, deploy_node, read_yaml
from cmdp_rl.population.spec import Population, population
from cmdp_rl.run.checkpoint import CheckpointError, load_checkpoint
from cmdp_rl.run.migrations import member, migrate, recorded_defaults, saved_config_defaults, saved_config_nodes
from cmdp_rl.run.resume import check_resume_config, resumed_raw


def resume_population(
    out: str | Path, requested: Mapping[str, Any] | None = None, explicit: Iterable[str] = (), trust: bool = False
) -> Population:
    """The population in ``out`` to continue, as :func:`resume_config` continues a run: its own config
    (``population.yaml``) with the options named in ``explicit`` taken from ``requested`` where a
    run's resume may change them, and its checkpoint (``checkpoint.pt``, else an older population's
    ``population.pt``; an older format's only with ``trust``) migrated to the current layout. A population whose
    agents trained one after another has no checkpoint of its own: each agent resumes as a run."""
    out = Path(out)
    if not (out / POPULATION_CONFIG).is_file():
        raise CheckpointError(f"resume: no {POPULATION_CONFIG} in {out}")
    saved_raw = read_yaml(out / POPULATION_CONFIG, "resume")
    state, stacked = None, False
    ckpt = next((out / n for n in (CHECKPOINT, POPULATION_CHECKPOINT) if (out / n).is_file()), None)
    if ckpt is not None:
        saved = load_checkpoint(ckpt, trust=trust)
        stacked = "update" in saved
        state = migrate(saved)
    # In the current layout: the stacked layout predates defaults that its config does not name
    # (saved_config_defaults); a population.yaml names only what its author gave, so any other has
    # only its flat multiplier and deployment options moved into their nodes.
    saved_raw = saved_config_defaults(saved_raw) if stacked else deploy_node(saved_config_nodes(saved_raw))
    if state is not None and not stacked and "members" in state:  # defaults changed since: as its members ran
        saved_raw = recorded_defaults(saved_raw, member(state)["config"])
    deploy = saved_raw.setdefault("deploy", {})
    if state is not None and deploy.get("policy", "auto") == "auto":  # as its agents resolved it (the
        # last iterate, before populations deployed what a run deploys)
        deploy["policy"] = deploy_node(member(state)["config"])["deploy"]["policy"] if "members" in state else "last"
    raw = resumed_raw(saved_raw, requested or {}, explicit, out)
    if raw.get("population") != saved_raw.get("population"):
        raise ConfigError(f"population cannot change when resuming {out}")
    before, after = population(saved_raw), population(raw, resume=True, state=state)
    for a, b in zip(before.cfgs, after.cfgs):
        check_resume_config(a, b)
    return after
