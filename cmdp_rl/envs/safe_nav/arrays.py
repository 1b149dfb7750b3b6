"""One definition of the task logic for both physics backends of ``env=safe_nav``.

The reward, cost and lidar functions are written once against the operations numpy and torch
share (``sqrt``, ``sum(..., axis=)``, ``clip``, ``where``, ``arctan2``, ...): on ``env.physics=mujoco``
they run on numpy float64 arrays, exactly the arithmetic the reference uses; on
``env.physics=mjwarp`` on torch tensors on the simulation's device. These helpers cover the few
places where the two libraries differ (allocation, the host copy the layout sampler needs).
"""

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


def arange(like: Array, n: int) -> Array:
    """``0, 1, ..., n - 1`` in ``like``'s library, device and float type."""
    if isinstance(like, torch.Tensor):
        return torch.arange(n, dtype=like.dtype, device=like.device)
    return np.arange(n, dtype=like.dtype)


def to_host(x: Array) -> np.ndarray:
    """A numpy view or copy of ``x`` (on the CPU), for the host-side layout sampler."""
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def like(values: Any, ref: Array) -> Array:
    """``values`` as an array of ``ref``'s library, device and float type."""
    if isinstance(ref, torch.Tensor):
        return torch.as_tensor(np.asarray(values), dtype=ref.dtype, device=ref.device)
    return np.asarray(values, dtype=ref.dtype)


__all__ = ["Array", "arange", "like", "namespace", "to_host", "zeros"]
