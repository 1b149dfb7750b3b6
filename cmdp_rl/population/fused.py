"""The training pass of every agent's actor and both critics as one autograd node.

Where the actor's output network and the two critics are tanh MLPs of the same shapes (Reach1D:
one action dimension, one cost), the population runs them as one stack of 3P networks
(``PopulationAgent.training_pass``). Written through autograd, each minibatch step then builds a
dozen nodes per layer: the weights' ``cat`` from views of the two flat leaves, whose backward
allocates a zero ``[P, n]`` gradient per parameter view and adds them up, ``baddbmm`` whose
backward computes the first layer's weight gradient in a slow layout (``g^T x`` with two input
columns: 2.2 ms at P = 64 against 0.3 ms as ``(x^T g)^T``), and the activation's Python function.
:class:`FusedTanhMLP` does the same arithmetic (``nn.Linear`` as ``baddbmm`` per network, tanh as
``policies.mlp.Tanh`` computes it, tanh's backward ``g (1 - y^2)``) in one forward and one hand-
written backward that writes each weight's gradient straight into the two flat gradients.
Measured effect: docs/population.md.
"""

from __future__ import annotations

from typing import Sequence

import torch

from cmdp_rl.policies.mlp import Tanh


def _tanh(z: torch.Tensor) -> torch.Tensor:
    """``policies.mlp.Tanh`` in place on ``z`` (a fresh ``baddbmm`` output, not needed after)."""
    if z.device.type != "cpu" or z.numel() < Tanh.MIN_NUMEL:
        return z.tanh_()
    return z.mul_(2).sigmoid_().mul_(2).sub_(1)


class FusedTanhMLP(torch.autograd.Function):
    """``x [3P, B, in]`` through ``L`` linear layers with tanh between them; layer ``l``'s weight
    and bias of network group ``s`` (actor, reward, cost: P networks each) are
    ``flats[s][:, slices[s][layer]]``. Returns ``[3P, B, out]``."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, actor: torch.Tensor, critics: torch.Tensor, layout: tuple) -> torch.Tensor:
        # layout: per layer, per group (0 actor, 1 reward, 2 cost): (flat index, w_from, w_to, b_from, b_to),
        # and the layer's (out, in).
        flats = (actor, critics)
        weights, hs = [], [x]
        h = x
        for layer, (groups, (out, inp)) in enumerate(layout):
            p = actor.shape[0]
            w = torch.cat([flats[f][:, wa:wb].view(p, out, inp) for f, wa, wb, _, _ in groups])
            b = torch.cat([flats[f][:, ba:bb] for f, _, _, ba, bb in groups])
            h = torch.baddbmm(b.unsqueeze(1), h, w.transpose(1, 2))
            weights.append(w)
            if layer < len(layout) - 1:
                h = _tanh(h)
                hs.append(h)
        ctx.layout = layout
        ctx.save_for_backward(*weights, *hs)
        ctx.shapes = (actor.shape, critics.shape)
        return h

    @staticmethod
    def backward(ctx, g: torch.Tensor):
        layout = ctx.layout
        n = len(layout)
        saved = ctx.saved_tensors
        weights, hs = saved[:n], saved[n:]
        grads = (g.new_zeros(ctx.shapes[0]), g.new_zeros(ctx.shapes[1]))
        p = ctx.shapes[0][0]
        g = g.contiguous()
        for layer in range(n - 1, -1, -1):
            groups, (out, inp) = layout[layer]
            h = hs[layer]
            # dW = g^T h, computed as (h^T g)^T: the faster layout when ``in`` is small.
            gw = torch.bmm(h.transpose(1, 2), g).transpose(1, 2)
            gb = g.sum(1)
            for s, (f, wa, wb, ba, bb) in enumerate(groups):
                grads[f][:, wa:wb].view(p, out, inp).copy_(gw[s * p : (s + 1) * p])
                grads[f][:, ba:bb].copy_(gb[s * p : (s + 1) * p])
            if layer > 0:
                # fresh either way: tanh's backward may overwrite it. One output: an outer product,
                # the same single products as bmm's, at a quarter of its time.
                g = g * weights[layer] if out == 1 else torch.bmm(g, weights[layer])
                g = torch.ops.aten.tanh_backward.grad_input(g, hs[layer], grad_input=g)
        return None, grads[0], grads[1], None


def layout(
    actor,
    critics,
    prefixes: Sequence[tuple[int, str]],
    linear_indices: Sequence[int],
    shapes: Sequence[tuple[int, int]],
) -> tuple:
    """The :class:`FusedTanhMLP` layout of layers ``linear_indices`` (their ``nn.Sequential``
    indices) for the groups ``prefixes`` (flat index 0 = ``actor``, 1 = ``critics``; parameter
    name prefix)."""
    stacks = (actor, critics)
    out = []
    for i, shape in zip(linear_indices, shapes):
        groups = []
        for f, prefix in prefixes:
            wa, wb = stacks[f].offsets[f"{prefix}.{i}.weight"]
            ba, bb = stacks[f].offsets[f"{prefix}.{i}.bias"]
            groups.append((f, wa, wb, ba, bb))
        out.append((tuple(groups), tuple(shape)))
    return tuple(out)


__all__ = ["FusedTanhMLP", "layout"]
