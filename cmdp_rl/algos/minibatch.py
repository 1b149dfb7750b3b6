"""The bookkeeping of the minibatch epochs the update loops share (ppo.py's, CUP's projection, the
trust-region family's critic regression): a run's minibatch order, the statistics' means over the
minibatches each member evaluated, and a batch's rows per member."""

from __future__ import annotations

from typing import Any, Iterator, Mapping, Sequence

import torch
from tensordict import TensorDictBase


def minibatches(
    data: Mapping[str, torch.Tensor], num_minibatches: int, epochs: int = 1
) -> Iterator[tuple[int, dict[str, torch.Tensor]]]:
    """Yield ``(epoch, minibatch)`` for ``epochs`` passes over ``data`` (training units), each in a fresh
    order from torch's global generator, split into ``num_minibatches`` equal slices (the remainder
    skipped); one gather per pass, each minibatch a view. A caller stops early by breaking."""
    total = next(iter(data.values())).shape[0]
    size = total // num_minibatches
    if size < 1:
        raise ValueError(f"{num_minibatches} minibatches of {total} units: at most {total} allowed")
    device = next(iter(data.values())).device
    for epoch in range(epochs):
        perm = torch.randperm(total, device=device)
        shuffled = {k: v[perm] for k, v in data.items()}
        for i in range(num_minibatches):
            yield epoch, {k: v[i * size : (i + 1) * size] for k, v in shuffled.items()}


class Tally:
    """Each statistic summed over the minibatches a member evaluated, and their count."""

    def __init__(self) -> None:
        self.sums: dict[str, torch.Tensor] = {}
        self.count: Any = 0

    def add(self, stats: dict[str, torch.Tensor], evaluated: Any = True) -> None:
        """``evaluated``: True (every member), or which members evaluated this minibatch (a ``[P]`` mask)."""
        self.count = self.count + (1 if evaluated is True else evaluated.float())
        for k, v in stats.items():
            v = v.detach() if evaluated is True else torch.where(evaluated, v.detach(), 0.0)
            self.sums[k] = self.sums[k] + v if k in self.sums else v

    def means(self) -> dict[str, torch.Tensor]:
        return {k: v / self.count for k, v in self.sums.items()}


def stopped(active: Any) -> bool:
    """Whether KL early stopping has stopped every member (a host sync only once a limit acts)."""
    return active is not True and not bool(active.any())


def member_rows(batch: TensorDictBase, count: int) -> list[TensorDictBase]:
    """Each member's rows of ``batch``: the batch itself for one."""
    n = batch.shape[0] // count
    return [batch] if count == 1 else [batch[i * n : (i + 1) * n] for i in range(count)]


def joined(parts: Sequence[Any]) -> Any:
    """The members' tensors (or dicts of them) back in one, in member order: the one for one."""
    if len(parts) == 1:
        return parts[0]
    if isinstance(parts[0], dict):
        return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
    return torch.cat(parts)


def member_stats(means: dict[str, torch.Tensor], count: int) -> list[dict[str, float]]:
    """Statistics (each a number, or one per member) as each member's numbers: one host sync."""
    values = torch.stack(list(means.values())).reshape(len(means), count).tolist()
    return [{k: values[s][i] for s, k in enumerate(means)} for i in range(count)]


__all__ = ["Tally", "joined", "member_rows", "member_stats", "minibatches", "stopped"]
