"""torch's intra-op thread count from the run config's ``threads``: torch's default of one per core oversubscribes
the cores for this toolkit's small networks as soon as anything runs beside it (docs/guide/design.md)."""

from __future__ import annotations

from typing import Any

import torch


def apply_threads(cfg: Any) -> None:
    """``torch.set_num_threads(cfg.threads)`` (process-wide, as torch's setting is)."""
    if torch.get_num_threads() != cfg.threads:
        torch.set_num_threads(cfg.threads)
