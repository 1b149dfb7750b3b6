"""Hydra callbacks of ``train.py`` (``hydra.callbacks`` in ``configs/config.yaml``).

Hydra creates the run (or sweep) directory itself, before ``train.py``'s code runs, and an
uncreatable one (``hydra.run.dir=/proc/x``) ends in a pathlib traceback there. This callback runs
just before that, on the same resolved directory (Hydra's ``now`` resolver caches its value in the
config, so the directory checked is the one Hydra then uses), and stops with one line, exit 2.
"""

from __future__ import annotations

import sys
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from cmdp_rl.run.rundir import RunDirError, ensure_writable

EXIT_STATUS = 2


def _check(config: DictConfig, key: str) -> None:
    try:
        ensure_writable(str(OmegaConf.select(config, key)))
    except RunDirError as exc:
        print(f"cannot write outputs: {exc}", file=sys.stderr)
        sys.exit(EXIT_STATUS)


class CheckOutputDir(Callback):
    """Stop before the job if its output directory cannot be created or written."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        _check(config, "hydra.run.dir")

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        _check(config, "hydra.sweep.dir")
