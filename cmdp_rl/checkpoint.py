"""Checkpoints: written atomically, checked on load."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

# 2: adds what a resume needs (collector and env state, generators, training time).
FORMAT_VERSION = 2


class CheckpointError(RuntimeError):
    """A checkpoint is missing, unreadable, or was written by another algorithm or policy."""


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> None:
    """Write ``state`` to ``path`` so that a kill at any moment leaves the old file or the new one,
    never a partial one: write a sibling temp file, fsync it, then rename over the target."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        torch.save({"format": FORMAT_VERSION, **state}, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    # Make the rename itself durable (a power cut after a kill-proof rename could still lose it).
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def load_checkpoint(path: str | Path, algo: str | None = None, policy: str | None = None) -> dict[str, Any]:
    """Load a checkpoint, refusing one for another algorithm or policy than expected."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint: no file at {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises several types for a truncated or foreign file
        raise CheckpointError(f"checkpoint: {path} is corrupt or not a cmdp_rl checkpoint ({exc})") from exc
    if not isinstance(state, dict) or state.get("format") != FORMAT_VERSION:
        raise CheckpointError(f"checkpoint: {path} is not a cmdp_rl checkpoint of format {FORMAT_VERSION}")
    for field, expected in (("algo", algo), ("policy", policy)):
        if expected is not None and state.get(field) != expected:
            raise CheckpointError(
                f"checkpoint: {path} was written by {field}={state.get(field)!r}, but this run uses {field}={expected!r}"
            )
    return state
