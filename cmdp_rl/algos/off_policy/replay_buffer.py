"""The off-policy algorithms' replay buffer: torchrl's ``TensorDictReplayBuffer`` of single
transitions, reward and cost side by side as in the on-policy batch, saved whole in a checkpoint."""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import LazyMemmapStorage, LazyTensorStorage, TensorDictReplayBuffer

from cmdp_rl.rollout import keys

# What a transition keeps in the buffer: reward and cost are twins, as in the batch. A truncated
# step keeps its final observation under "next" and bootstraps from it (only termination masks).
STORED = (
    keys.OBS,
    keys.ACTION,
    (keys.NEXT, keys.OBS),
    (keys.NEXT, keys.REWARD),
    (keys.NEXT, keys.COST),
    (keys.NEXT, keys.TERMINATED),
)


class Replay:
    """torchrl's ``TensorDictReplayBuffer`` of single transitions (:data:`STORED`), uniform sampling
    from torch's generator (seeded by the run; restored on resume)."""

    def __init__(self, size: int, batch_size: int, storage: str, device: torch.device | str = "cpu") -> None:
        store = (
            LazyMemmapStorage(size, device=device) if storage == "memmap" else LazyTensorStorage(size, device=device)
        )
        self.buffer = TensorDictReplayBuffer(storage=store, batch_size=batch_size)

    def __len__(self) -> int:
        return len(self.buffer)

    def add(self, batch: TensorDictBase) -> int:
        """Add the ``[N, T]`` batch's transitions; returns how many."""
        flat = batch.select(*STORED).reshape(-1)
        self.buffer.extend(flat)
        return flat.shape[0]

    def sample(self) -> TensorDictBase:
        return self.buffer.sample()

    def newest(self, n: int) -> TensorDictBase:
        """The ``n`` transitions added last (all, if fewer are stored), oldest first: the writer's
        cursor is the next row it overwrites, so the newest rows end just before it, modulo capacity."""
        n = min(n, len(self.buffer))
        cursor = self.buffer.writer.state_dict()["_cursor"]
        return self.buffer.storage.get((cursor - n + torch.arange(n)) % self.buffer.storage.max_size)

    def state_dict(self) -> dict:
        """The stored transitions in storage order (only the filled rows, not the whole capacity)
        and the writer's cursor: a buffer loading it samples the same indices to the same data."""
        n = len(self.buffer)
        data = self.buffer.storage.get(torch.arange(n)).to_dict() if n else {}
        return {"data": data, "len": n, "writer": self.buffer.writer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        if state["len"]:
            self.buffer.extend(TensorDict(state["data"], batch_size=[state["len"]]))
        self.buffer.writer.load_state_dict(state["writer"])
