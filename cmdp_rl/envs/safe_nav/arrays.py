"""The task logic of ``env=safe_nav`` is written once for both physics backends, against the operations
numpy and torch share: numpy float64 on ``env.physics=mujoco`` (the reference's arithmetic), torch on
the device on ``mjwarp``. These helpers cover where the two libraries differ."""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
import torch

Array = Any  # a numpy array or a torch tensor


def namespace(x: Array) -> ModuleType:
    """The module whose functions operate on ``x``: torch for a tensor, else numpy."""
    return torch if isinstance(x, torch.Tensor) else np


def zeros(like: Array, shape: tuple[int, ...], dtype: str = "float") -> Array:
    """Zeros of ``shape`` in ``like``'s library, device and float type (``dtype="bool"``: flags)."""
    if isinstance(like, torch.Tensor):
        kind = torch.bool if dtype == "bool" else like.dtype
        return torch.zeros(shape, dtype=kind, device=like.device)
    return np.zeros(shape, dtype=bool if dtype == "bool" else like.dtype)


def to_host(x: Array) -> np.ndarray:
    """A numpy view or copy of ``x`` (on the CPU), for the host-side layout sampler."""
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def distance(a: Array, b: Array) -> Array:
    """Euclidean distance over the last axis: the reference's ``sqrt(sum(square(a - b)))``."""
    xp = namespace(a)
    return xp.sqrt(xp.sum(xp.square(a - b), axis=-1))


def like(values: Any, ref: Array) -> Array:
    """``values`` as an array of ``ref``'s library, device and float type."""
    if isinstance(ref, torch.Tensor):
        return torch.as_tensor(np.asarray(values), dtype=ref.dtype, device=ref.device)
    return np.asarray(values, dtype=ref.dtype)
