"""A run directory belongs to one run.

A new run into a directory that already holds a run (finished or not) stops before it writes
anything, with one line saying how to continue that run (``resume=<dir>``) or replace it
(``overwrite=true``). While a run lives, it holds an advisory lock on ``<dir>/.run.lock``
(``fcntl.flock``): a second process into the same directory, new run or resume, is refused, and the
kernel drops the lock when the holder dies, killed or not, so a crashed run never blocks its resume.

Within one process the lock is counted: ``train.py``'s Hydra callback claims the directory before
Hydra writes into it and keeps it for the process's life; ``train()`` claims it again (a no-op then),
as a script calling ``train()`` directly needs.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from cmdp_rl.run.rundir import (
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
    RunDirError,
    ensure_writable,
)

LOCK = ".run.lock"
# What a run leaves behind from its first write on: a directory holding any of these holds a run.
RUN_FILES = (CONFIG, METRICS, CHECKPOINT, EVAL, POPULATION_CONFIG, POPULATION_CHECKPOINT)
# What overwrite=true removes: every output of a run. Hydra's record and log too where the claim
# comes before Hydra writes them (train.py's callback), never after (a sweep's job).
OUTPUTS = (*RUN_FILES, RUN_INFO, ERROR, POPULATION_SUMMARY, "wandb_id.txt", TENSORBOARD, "wandb", "videos", "agents")
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


def _finished(run_dir: Path) -> bool:
    """Whether a run (its ``eval.json``) or a population (its ``population.json``) finished there."""
    return (run_dir / EVAL).is_file() or (run_dir / POPULATION_SUMMARY).is_file()


def _key(run_dir: str | Path) -> Path:
    return Path(run_dir).resolve()


def _busy(path: Path, fd: int) -> RunDirTaken:
    holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "another process"
    os.close(fd)
    return RunDirTaken(
        f"run directory {path} is in use by a running run (process {holder}); wait for it to end, "
        "or start this run in another directory"
    )


def _lock(path: Path, create: bool) -> int | None:
    """Take ``path``'s lock without waiting; None if there is no lock file and ``create`` is false."""
    flags = os.O_RDWR | (os.O_CREAT if create else 0)
    try:
        fd = os.open(path / LOCK, flags, 0o644)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise _busy(path, fd) from None
    return fd


def _record_holder(fd: int) -> None:
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)


def acquire(run_dir: str | Path, new_run: bool, overwrite: bool = False, hydra_record: bool = False) -> Path:
    """Claim ``run_dir`` for this process and hold its lock until :func:`release` (or the process
    ends). ``new_run``: refuse a directory that holds a run, unless ``overwrite`` (then its outputs
    are removed first); a resume (``new_run=False``) only takes the lock. Nothing in a refused
    directory is created or changed. Claiming a directory this process holds counts one more.
    ``hydra_record``: overwrite removes Hydra's record and log as well (:data:`HYDRA_RECORD`)."""
    path = _key(run_dir)
    if path in _held:
        fd, count = _held[path]
        _held[path] = (fd, count + 1)
        return path
    fd = _lock(path, create=False) if path.is_dir() else None  # a live run holds it: refuse first
    try:
        if new_run and holds_run(path) and not overwrite:
            raise RunDirTaken(
                f"run directory {path} already holds {'a finished' if _finished(path) else 'an unfinished'} "
                f"run: continue it with resume={run_dir}, or replace it with overwrite=true"
            )
        ensure_writable(path)
        if fd is None:
            fd = _lock(path, create=True)
    except BaseException:
        if fd is not None:
            os.close(fd)
        raise
    _record_holder(fd)
    if new_run and overwrite:
        remove_outputs(path, OUTPUTS + (HYDRA_RECORD if hydra_record else ()))
    _held[path] = (fd, 1)
    return path


def release(run_dir: str | Path) -> None:
    """Give back one claim; the last one unlocks the directory (the lock file stays)."""
    path = _key(run_dir)
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
