"""Shuffled minibatches over a batch's training units: the loop PPO's update and CPO's critic fit share."""

from __future__ import annotations

from typing import Iterator, Mapping

import torch


def minibatches(
    data: Mapping[str, torch.Tensor], num_minibatches: int, epochs: int = 1
) -> Iterator[tuple[int, dict[str, torch.Tensor]]]:
    """Yield ``(epoch, minibatch)`` for ``epochs`` passes over ``data`` (tensors with the same
    leading size: training units), each pass in a fresh random order (torch's global generator, so
    a seeded run repeats), split into ``num_minibatches`` equal slices. Units left over by the
    division are skipped in that pass (as before, so numbers did not move). One gather per pass;
    each minibatch is then a view. A caller may stop early (e.g. KL early stopping) by breaking."""
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


__all__ = ["minibatches"]
