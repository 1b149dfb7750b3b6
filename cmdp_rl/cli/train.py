"""Train a constrained-RL agent: ``cmdp-train algo=ppo_lag env=reach1d [overrides]`` (also ``python -m cmdp_rl`` and,
in a checkout, ``python train.py``). Options: ``configs/``; outputs: Hydra's run directory. ``resume=<run dir>``
continues that run in its directory (``cmdp_rl/run/resume.py``); sweeps are Hydra multiruns (``-m``)."""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from cmdp_rl import ConfigError, TrainingDiverged, load_config, train
from cmdp_rl.config.run_config import CONFIG_SOURCE
from cmdp_rl.config.saved import ERROR, EVAL, POPULATION_CONFIG
from cmdp_rl.population.resume import resume_population
from cmdp_rl.population.spec import population, population_active
from cmdp_rl.run.checkpoint import CheckpointError
from cmdp_rl.run.ownership import RunDirTaken, acquire, holds_run, release, remove_outputs, resumable
from cmdp_rl.run.resume import resume_config
from cmdp_rl.run.rundir import RunDirError, record_failure
from cmdp_rl.tune.trial import trial_observers

# How a single run ends on each error (inside a sweep the command raises instead: see _fail).
EXIT_CODES = (
    (RunDirError, 2, "cannot write outputs"),
    (ConfigError, 2, "config error"),
    (CheckpointError, 2, "cannot resume"),
    (TrainingDiverged, 3, "training stopped"),
)


def _if_resumable(resume: str | None, then: str, otherwise: str) -> str:
    """For `hydra.run.dir` in configs/config.yaml: a resumed run writes into its own directory.
    Only a directory with a checkpoint counts, so a mistyped path is reported, not created."""
    return then if resumable(resume) else otherwise


def _record_subdir(resume: str | None, overwrite: bool, output_dir: str, resume_subdir: str) -> str | None:
    """For `hydra.output_subdir`: Hydra's record of a resume goes beside the original one; into a
    directory that holds another run (a sweep's job whose directory is taken: train() refuses it),
    Hydra writes no record at all, so that the run there keeps its files as they were."""
    if resumable(resume):
        return resume_subdir
    return None if holds_run(output_dir) and not overwrite else ".hydra"


OmegaConf.register_new_resolver("cmdp.if_resumable", _if_resumable)
OmegaConf.register_new_resolver("cmdp.record_subdir", _record_subdir)


def _fail(exc: Exception, run_dir: str | None) -> None:
    if run_dir is not None and not isinstance(exc, RunDirTaken):  # a taken directory is another run's
        try:
            record_failure(run_dir, exc)
        except OSError:  # a run directory that cannot be written: the message below says so
            pass
    if HydraConfig.get().mode == RunMode.MULTIRUN:
        # Raise, never sys.exit, inside a sweep: Hydra then marks only this job failed, lets the
        # others finish (each writes its own directory) and raises once all are done. SystemExit
        # would bypass Hydra's per-job handling and stop the whole sweep.
        raise exc
    for kind, code, what in EXIT_CODES:
        if isinstance(exc, kind):
            print(f"{what}: {exc}", file=sys.stderr)
            sys.exit(code)
    raise exc


@hydra.main(config_path=CONFIG_SOURCE, config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    raw = OmegaConf.to_container(cfg, resolve=True)
    # A new run's directory records why it failed (error.txt); a resume leaves the run it names as
    # the resume machinery does (a refused resume must not touch a finished run).
    new_dir = None if raw.get("resume") else HydraConfig.get().runtime.output_dir
    if new_dir is not None:
        try:  # first: a directory another run holds is refused before anything is written into it
            acquire(new_dir, new_run=True, overwrite=bool(raw.get("overwrite")))
        except RunDirError as exc:
            _fail(exc, None if isinstance(exc, RunDirTaken) else new_dir)
    try:
        _main(raw, new_dir)
    finally:
        if new_dir is not None:
            release(new_dir)


def _main(raw: dict, new_dir: str | None) -> None:
    try:
        if raw.get("resume"):  # a run's or a population's directory: its own config, RESUMABLE's changes
            explicit = [
                o.key_or_group for o in OverridesParser.create().parse_overrides(list(HydraConfig.get().overrides.task))
            ]
            if (Path(raw["resume"]) / POPULATION_CONFIG).is_file():
                trust = bool(raw.get("trust_checkpoint")) and "trust_checkpoint" in explicit
                run_cfg = resume_population(raw["resume"], raw, explicit, trust)
            else:
                run_cfg = resume_config(raw["resume"], raw, explicit)
        elif population_active(raw.get("population")):  # several agents in one process (docs/population.md)
            run_cfg = population(raw)
        else:
            run_cfg = load_config(raw)
    except (ConfigError, CheckpointError) as exc:
        _fail(exc, new_dir)
    try:
        if new_dir is not None:
            remove_outputs(new_dir, (EVAL, ERROR))  # an earlier result or error must not outlive this run
        # A resumed run writes into its own directory, whatever hydra.run.dir says.
        # A search's job hands its trial an observer of the training curve (tune/trial.py).
        observers = trial_observers(HydraConfig.get().job.env_set)
        train(run_cfg, new_dir or raw.get("resume"), observers=observers)
    except Exception as exc:  # noqa: BLE001 - every failure is recorded, then handled by _fail
        _fail(exc, new_dir)


if __name__ == "__main__":
    main()
