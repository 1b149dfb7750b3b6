"""Checkpoints: written atomically, loaded without running anything from the file (docs/checkpoints.md).

A checkpoint holds tensors, numbers, strings and plain containers of them, so torch's safe unpickler
(``torch.load(weights_only=True)``) reads it and loading someone else's run cannot run their code. No type is
allow-listed: numpy values and deques are written as tagged tensors and lists (:func:`encode`, :func:`decode`), and
anything else is refused when saving, naming where it sits. Older formats, which only the full unpickler reads, load
only when trusted (``trust_checkpoint=true``); :mod:`cmdp_rl.run.migrations` brings them to this one."""

from __future__ import annotations

import collections
import os
import pickle
import re
from pathlib import Path
from typing import Any

import numpy as np
import torch

# 4: one layout for a run and a population of P (the shared state, one entry per member under "members");
# 3: data only (the safe unpickler reads it); 2: adds what a resume needs. docs/checkpoints.md has each layout.
FORMAT_VERSION = 4
SAFE_FORMAT = 3  # the first format of data only: read without asking for trust
OLDEST_FORMAT = 2  # the oldest cmdp_rl.run.migrations brings to FORMAT_VERSION

NDARRAY = "__ndarray__"
NUMPY_SCALAR = "__numpy_scalar__"
DEQUE = "__deque__"

# What the older formats pickled whole (numpy objects, deques, a pickled MuJoCo data or Safety-Gymnasium world's
# bytes): a file whose only non-data globals are these is refused as an old cmdp_rl checkpoint.
_OLD_FORMAT_GLOBALS = re.compile(r"^(numpy\.|collections\.deque$|builtins\.bytes$|_codecs\.encode$)")


class CheckpointError(RuntimeError):
    """A checkpoint is missing, unreadable, or was written by another algorithm or policy."""


class UnsafeCheckpointError(CheckpointError):
    """A checkpoint that only Python's full unpickler reads: loading it would run code from the file."""


def encode(value: Any, where: str = "state") -> Any:
    """``value`` as tensors, numbers, strings and plain containers: a numpy array as ``{NDARRAY: tensor}`` (the same
    bytes), a numpy scalar as ``{NUMPY_SCALAR: 0-d tensor}``, a deque as ``{DEQUE: items, "maxlen": n}``;
    ``TypeError`` naming ``where`` for anything else."""
    if isinstance(value, np.generic):  # first: numpy's float64 is also a Python float
        return {NUMPY_SCALAR: encode(np.asarray(value), where)[NDARRAY]}
    if value is None or isinstance(value, (bool, int, float, str, torch.Tensor, torch.dtype, torch.Size)):
        return value
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject or value.dtype.kind in "USV":
            raise TypeError(f"checkpoint: {where} is a numpy array of {value.dtype}, not numbers")
        native = value.astype(value.dtype.newbyteorder("="), copy=False)
        # (ascontiguousarray makes a 0-d array 1-d: the reshape keeps the shape)
        return {NDARRAY: torch.from_numpy(np.ascontiguousarray(native)).reshape(native.shape)}
    if isinstance(value, collections.deque):
        return {DEQUE: [encode(v, f"{where}[{i}]") for i, v in enumerate(value)], "maxlen": value.maxlen}
    if isinstance(value, dict):
        out = collections.OrderedDict() if isinstance(value, collections.OrderedDict) else {}
        for k, v in value.items():
            if not isinstance(k, (str, int)):
                raise TypeError(f"checkpoint: {where} has a key of type {type(k).__name__}, not str or int")
            out[k] = encode(v, f"{where}.{k}")
        return out
    if isinstance(value, (list, tuple)):
        items = [encode(v, f"{where}[{i}]") for i, v in enumerate(value)]
        return items if isinstance(value, list) else tuple(items)
    raise TypeError(
        f"checkpoint: {where} is a {type(value).__module__}.{type(value).__name__}, which a checkpoint cannot hold"
    )


def decode(value: Any) -> Any:
    """The inverse of :func:`encode`."""
    if isinstance(value, dict):
        if NDARRAY in value and len(value) == 1:
            return value[NDARRAY].numpy()
        if NUMPY_SCALAR in value and len(value) == 1:
            return value[NUMPY_SCALAR].numpy()[()]
        if DEQUE in value and len(value) == 2:
            return collections.deque((decode(v) for v in value[DEQUE]), maxlen=value["maxlen"])
        mapping = collections.OrderedDict if isinstance(value, collections.OrderedDict) else dict
        return mapping((k, decode(v)) for k, v in value.items())
    if isinstance(value, list):
        return [decode(v) for v in value]
    if isinstance(value, tuple):
        return tuple(decode(v) for v in value)
    return value


def checkpoint_state(
    cfg: Any, iteration: int, step: int, time_s: float, members: list[dict], collector: Any, rng: Any, **more: Any
) -> dict[str, Any]:
    """A checkpoint (format 4, docs/checkpoints.md), a run's or a population's: what its members share
    (the iteration, each member's env ``step``s, the training time, the ``collector``'s state and the
    random state ``rng``), their entries (:func:`member_entry`) and ``more`` (a population's costs)."""
    shared = {"algo": cfg.algo.name, "policy": cfg.policy.name, "iteration": iteration, "step": step}
    return {**shared, "time_s": time_s, "collector": collector, "rng": rng, "members": members, **more}


def member_entry(run_cfg: dict[str, Any], algo: Any, final: Any = None) -> dict[str, Any]:
    """A member's entry of a checkpoint: its config, its algorithm's ``state_dict`` (networks,
    optimisers, its own state) and what it deploys (``final``, a ``deploy.final_policy.FinalPolicy``: its state)."""
    return {**(final.state_dict() if final else {}), "config": run_cfg, "algo_state": algo.state_dict()}


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> None:
    """Write ``state`` to ``path`` so that a kill at any moment leaves the old file or the new one,
    never a partial one: write a sibling temp file, fsync it, then rename over the target."""
    path = Path(path)
    data = {"format": FORMAT_VERSION, **encode(state)}  # before the file is opened: a refusal writes nothing
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        torch.save(data, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    # Make the rename itself durable (a power cut after a kill-proof rename could still lose it).
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def _what_it_holds(path: Path, exc: Exception) -> tuple[list[str], str]:
    """The globals (importable names) the file's pickle would call, found by reading its opcodes (nothing is run), and,
    for a file torch cannot scan (not a torch zip file), the first line of the safe unpickler's error."""
    try:
        return sorted(torch.serialization.get_unsafe_globals_in_checkpoint(path)), "no pickled object in it"
    except Exception:  # noqa: BLE001 - not a zip checkpoint: torch's own reason is all there is
        return [], str(exc).strip().splitlines()[0][:200]


def _old_format(path: Path, how: str) -> UnsafeCheckpointError:
    return UnsafeCheckpointError(
        f"checkpoint: {path} is in an older cmdp_rl format ({how}), and reading it runs code from the file; if you "
        f"trust who wrote it, convert the run once with `python -m cmdp_rl.run.convert {path.parent}`, or "
        "load it as is with trust_checkpoint=true (docs/checkpoints.md)"
    )


def _corrupt(path: Path, reason: object) -> CheckpointError:
    return CheckpointError(f"checkpoint: {path} is corrupt or not a cmdp_rl checkpoint ({reason})")


def _refusal(path: Path, found: list[str]) -> UnsafeCheckpointError:
    if all(_OLD_FORMAT_GLOBALS.match(g) for g in found):
        return _old_format(path, "numpy objects pickled whole, which only Python's full unpickler reads")
    return UnsafeCheckpointError(
        f"checkpoint: {path} holds {', '.join(found)}, which is not data: refused, nothing in it was run "
        "(a checkpoint holds tensors, numbers and strings only; docs/checkpoints.md)"
    )


def load_checkpoint(
    path: str | Path, algo: str | None = None, policy: str | None = None, trust: bool = False
) -> dict[str, Any]:
    """Load a checkpoint with torch's safe unpickler, refusing one for another algorithm or policy than expected. A file
    that needs the full unpickler raises :class:`UnsafeCheckpointError` unless ``trust`` (which runs whatever the file
    holds). The state comes back in the format it was written in (``state["format"]``);
    :func:`cmdp_rl.run.migrations.migrate` brings an older one to :data:`FORMAT_VERSION`."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint: no file at {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:  # torch's safe unpickler stopped: at something not data?
        if not trust:  # refused: what it would call, or nothing (a damaged or foreign file)
            found, reason = _what_it_holds(path, exc)
            raise (_refusal(path, found) if found else _corrupt(path, reason)) from None
        try:
            state = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as inner:  # noqa: BLE001 - torch raises several types for a foreign file
            raise _corrupt(path, inner) from None
    except Exception as exc:  # torch raises several types for a truncated or foreign file
        raise _corrupt(path, exc) from None
    version = state.get("format") if isinstance(state, dict) else None
    if not isinstance(version, int) or not OLDEST_FORMAT <= version <= FORMAT_VERSION:
        raise CheckpointError(
            f"checkpoint: {path} is not a cmdp_rl checkpoint of format {OLDEST_FORMAT} to {FORMAT_VERSION} "
            f"(format {version!r})"
        )
    if version < SAFE_FORMAT and not trust:  # its migration may unpickle bytes the file holds
        raise _old_format(path, f"format {version}, whose env state may hold pickled bytes")
    if version >= SAFE_FORMAT:
        state = decode(state)
    for field, expected in (("algo", algo), ("policy", policy)):
        if expected is not None and state.get(field) != expected:
            raise CheckpointError(
                f"checkpoint: {path} was written by {field}={state.get(field)!r}, but this run uses {field}={expected!r}"
            )
    return state
