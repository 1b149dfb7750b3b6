"""Hydra callbacks of ``train.py`` (``hydra.callbacks`` in ``configs/config.yaml``), run before Hydra creates the
run (or sweep) directory and writes its record there: an uncreatable directory stops in one line (exit 2) instead of
Hydra's pathlib traceback, and a single run claims its directory (``run/ownership.py``) for the process's life, so
a directory holding another run, or held by a live one, is refused with its files untouched. (Hydra's ``now``
resolver caches its value, so the directory checked is the one Hydra then uses.)"""

from __future__ import annotations

import sys
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from cmdp_rl.run.ownership import acquire, resumable
from cmdp_rl.run.rundir import RunDirError, ensure_writable

EXIT_STATUS = 2


def _check(config: DictConfig, key: str, claim: bool = False) -> None:
    """Stop in one line unless the directory at ``key`` can be written (and, with ``claim``, claimed)."""
    try:
        ensure_writable(str(OmegaConf.select(config, key)))
        if claim:  # a resume's hydra.run.dir is the run's own directory (configs/config.yaml)
            acquire(
                str(OmegaConf.select(config, key)),
                new_run=not resumable(OmegaConf.select(config, "resume")),
                overwrite=bool(OmegaConf.select(config, "overwrite", default=False)),
                hydra_record=True,  # Hydra writes its record and log after this
            )
    except RunDirError as exc:
        print(f"cannot write outputs: {exc}", file=sys.stderr)
        sys.exit(EXIT_STATUS)


class CheckOutputDir(Callback):
    """Stop before the job if its output directory cannot be created or written, or holds another run."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        _check(config, "hydra.run.dir", claim=True)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        _check(config, "hydra.sweep.dir")
