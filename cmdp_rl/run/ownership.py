"""A run directory belongs to one run (docs/architecture.md, "Run directories"): a new run into a directory that holds a
run stops before it writes anything, naming ``resume=<dir>`` and ``overwrite=true``; while a run lives it holds
``fcntl.flock`` on ``<dir>/.run.lock``, which the kernel drops when the process ends, killed or not, so a crashed run
never blocks its resume. Claims within one process are counted (``train.py``'s Hydra callback's, then ``train()``'s)."""

from __future__ import annotations

import fcntl
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from cmdp_rl.config.saved import (
    AGENTS_DIR,
    CHECKPOINT,
    CONFIG,
    ERROR,
    EVAL,
    METRICS,
    POPULATION_CHECKPOINT,
    POPULATION_CONFIG,
    POPULATION_SUMMARY,
    RUN_INFO,
    TENSORBOARD,
)
from cmdp_rl.run.rundir import RunDirError, ensure_writable

LOCK = ".run.lock"
# What a run leaves behind from its first write on: a directory holding any of these holds a run.
RUN_FILES = (CONFIG, METRICS, CHECKPOINT, EVAL, POPULATION_CONFIG, POPULATION_CHECKPOINT)
# What overwrite=true removes: every output of a run. Hydra's record and log too where the claim
# comes before Hydra writes them (train.py's callback), never after (a sweep's job).
OUTPUTS = (*RUN_FILES, RUN_INFO, ERROR, POPULATION_SUMMARY, "wandb_id.txt", TENSORBOARD, "wandb", "videos", AGENTS_DIR)
HYDRA_RECORD = (".hydra", "train.log")

_held: dict[Path, tuple[int, int]] = {}  # directory -> (lock file descriptor, claims in this process)


class RunDirTaken(RunDirError):
    """The directory holds another run, or a live process holds its lock."""


def resumable(resume: str | None) -> bool:
    """Whether ``resume`` names a directory a run can continue from: it holds a checkpoint, or is a
    population's (whose agents trained one after another keep their own checkpoints)."""
    markers = (CHECKPOINT, POPULATION_CHECKPOINT, POPULATION_CONFIG)
    return bool(resume) and any((Path(resume) / name).is_file() for name in markers)


def holds_run(run_dir: str | Path) -> bool:
    """Whether ``run_dir`` holds (part of) a run: any of :data:`RUN_FILES`."""
    return any((Path(run_dir) / name).exists() for name in RUN_FILES)


def _lock(path: Path, create: bool) -> int | None:
    """Take ``path``'s lock without waiting; None if there is no lock file and ``create`` is false."""
    try:
        fd = os.open(path / LOCK, os.O_RDWR | (os.O_CREAT if create else 0), 0o644)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "another process"
        os.close(fd)
        raise RunDirTaken(
            f"run directory {path} is in use by a running run (process {holder}); wait for it to end, "
            "or start this run in another directory"
        ) from None
    return fd


def acquire(run_dir: str | Path, new_run: bool, overwrite: bool = False, hydra_record: bool = False) -> Path:
    """Claim ``run_dir`` for this process and hold its lock until :func:`release` (or the process ends). ``new_run``:
    refuse a directory that holds a run, unless ``overwrite`` (then its outputs are removed first); a resume
    (``new_run=False``) only takes the lock. Nothing in a refused directory is created or changed. Claiming a directory
    this process holds counts one more. ``hydra_record``: overwrite removes Hydra's record and log too."""
    path = Path(run_dir).resolve()
    if path in _held:
        fd, count = _held[path]
        _held[path] = (fd, count + 1)
        return path
    fd = _lock(path, create=False) if path.is_dir() else None  # a live run holds it: refuse first
    try:
        if new_run and holds_run(path) and not overwrite:
            finished = (path / EVAL).is_file() or (path / POPULATION_SUMMARY).is_file()
            raise RunDirTaken(
                f"run directory {path} already holds {'a finished' if finished else 'an unfinished'} "
                f"run: continue it with resume={run_dir}, or replace it with overwrite=true"
            )
        ensure_writable(path)
        if fd is None:
            fd = _lock(path, create=True)
    except BaseException:
        if fd is not None:
            os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)  # the holder, named when another process is refused
    if new_run and overwrite:
        remove_outputs(path, OUTPUTS + (HYDRA_RECORD if hydra_record else ()))
    _held[path] = (fd, 1)
    return path


def release(run_dir: str | Path) -> None:
    """Give back one claim; the last one unlocks the directory (the lock file stays)."""
    path = Path(run_dir).resolve()
    fd, count = _held[path]
    if count > 1:
        _held[path] = (fd, count - 1)
        return
    del _held[path]
    os.close(fd)  # closing the only descriptor drops the flock


@contextmanager
def owned(run_dir: str | Path, new_run: bool, overwrite: bool = False) -> Iterator[Path]:
    """:func:`acquire` for the duration of a ``with`` block."""
    path = acquire(run_dir, new_run, overwrite)
    try:
        yield path
    finally:
        release(path)


def remove_outputs(run_dir: str | Path, names: tuple[str, ...] = OUTPUTS) -> None:
    """Remove a previous run's outputs (``names``) from ``run_dir``, for ``overwrite=true``."""
    for name in names:
        target = Path(run_dir) / name
        if target.is_dir() and not target.is_symlink():
            shutil.rmtree(target)
        else:
            target.unlink(missing_ok=True)
