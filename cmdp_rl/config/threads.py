"""torch's intra-op thread count, from the run config's ``threads``.

torch's default is one thread per core; for this toolkit's small networks that oversubscribes the
cores as soon as anything else runs beside it (docs/guide/design.md). ``load_config`` applies it, so
a script that builds its pieces from a loaded config runs as ``train.py`` does."""

from __future__ import annotations

from typing import Any

import torch


def apply_threads(cfg: Any) -> None:
    """``torch.set_num_threads(cfg.threads)`` (process-wide, as torch's setting is)."""
    if torch.get_num_threads() != cfg.threads:
        torch.set_num_threads(cfg.threads)
