"""The agents' networks as stacked parameters, and Adam on them.

Each agent's networks are built by the single-run code (``policies/mlp.py``, under the agent's
seed, so initialisation is the single run's), then copied into two leaf tensors, ``[P, n_actor]``
and ``[P, n_critic]``: every weight is a view of one of them with a leading agent dimension. Why:

- Adam is elementwise, so one Adam over ``[P, n]`` is P Adams, each exactly on its own agent
  (per-agent learning rates are a ``[P, 1]`` tensor); the update costs a dozen whole-tensor
  operations whatever P is.
- Gradient-norm clipping, which is not elementwise, reduces over dimension 1: one norm per agent.
- A layer is one ``baddbmm`` over the agents, bit for bit ``F.linear`` per agent on the shapes
  tried. ``torch.func.functional_call`` + ``vmap`` over the same stacked parameters lowers
  ``F.linear`` to the same batched matmul plus its own dispatch, and measured no faster at any P
  (docs/population.md, "baddbmm against vmap"), so the layers are written as ``baddbmm`` directly.
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from cmdp_rl.policies.agent import Agent


class StackedParams:
    """The parameters of ``modules`` of P agents (same architecture), flattened into one leaf
    ``[P, n]``; :meth:`view` gives a parameter stacked over the agents, ``[P, *shape]``."""

    def __init__(self, per_agent: Sequence[nn.Module], device: torch.device) -> None:
        first = list(per_agent[0].named_parameters())
        self.names = [n for n, _ in first]
        self.shapes = {n: p.shape for n, p in first}
        self.offsets: dict[str, tuple[int, int]] = {}
        at = 0
        for n, p in first:
            self.offsets[n] = (at, at + p.numel())
            at += p.numel()
        self.size = at
        rows = [torch.cat([p.detach().reshape(-1) for _, p in m.named_parameters()]) for m in per_agent]
        self.flat = torch.stack(rows).to(device).requires_grad_(True)

    @property
    def num_agents(self) -> int:
        return self.flat.shape[0]

    def view(self, name: str) -> torch.Tensor:
        a, b = self.offsets[name]
        return self.flat[:, a:b].view(self.num_agents, *self.shapes[name])

    def row(self, t: torch.Tensor, i: int) -> dict[str, torch.Tensor]:
        """Agent ``i``'s row of ``t`` (``[P, n]``: these parameters, or Adam's moments of them) by
        parameter name, as views in its single-run module's shapes."""
        return {n: t[i, a:b].view(self.shapes[n]) for n, (a, b) in self.offsets.items()}

    def grad_norms(self) -> torch.Tensor:
        """Each agent's gradient norm over all of these parameters, ``[P]``."""
        return torch.linalg.vector_norm(self.flat.grad, dim=1)

    def clip_grad_norm_(self, max_norm: float) -> None:
        """``nn.utils.clip_grad_norm_`` per agent: each agent's gradient scaled by
        ``min(1, max_norm / (norm + 1e-6))`` (the same coefficient as torch's)."""
        coef = (max_norm / (self.grad_norms() + 1e-6)).clamp_(max=1.0)
        self.flat.grad.mul_(coef.unsqueeze(1))


class StackedAdam:
    """Adam (Kingma & Ba, 2015, Algorithm 1) on a ``[P, n]`` leaf, with one learning rate per agent.

    The formulas are torch's (``m`` by ``lerp``, bias corrections in float64 on the host, as
    ``torch.optim.Adam``'s fused CPU kernel computes its step size and ``sqrt(1 - beta2^t)``); each
    agent's step matches the single run's ``Adam(fused=True)`` to float rounding, not bit for bit
    (measured: 1e-7 apart after 20 steps; the fused kernel's vector code rounds differently).
    Written by hand because torch's Adam takes one learning rate per parameter group, and an
    agent's row of a stacked tensor cannot be a group of its own.
    """

    def __init__(
        self, params: torch.Tensor, lr: Sequence[float], betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8
    ) -> None:
        self.params = params
        self.lr = torch.tensor(list(lr), dtype=torch.float64)
        self.beta1, self.beta2 = betas
        self.eps = eps
        # Steps taken per agent: an agent stopped by KL early stopping takes none (torch's Adam
        # keeps one count per parameter; here one per row).
        self.steps = torch.zeros(params.shape[0], dtype=torch.float64)
        self.exp_avg = torch.zeros_like(params)
        self.exp_avg_sq = torch.zeros_like(params)

    @torch.no_grad()
    def step(self, active: torch.Tensor | None = None) -> None:
        """One Adam step of every agent, or of the agents where ``active`` (``[P]`` bool) holds:
        the others' parameters and moments stay as they are."""
        g = self.params.grad
        if active is not None:
            keep = ~active.unsqueeze(1).to(g.device)
            old = (self.params.clone(), self.exp_avg.clone(), self.exp_avg_sq.clone())
        self.steps += 1 if active is None else active.to(torch.float64).cpu()
        self.exp_avg.lerp_(g, 1 - self.beta1)
        self.exp_avg_sq.mul_(self.beta2).addcmul_(g, g, value=1 - self.beta2)
        # The bias corrections in float64 on the host, as torch's fused CPU kernel computes them.
        bias1 = 1 - self.beta1**self.steps
        bias2_sqrt = (1 - self.beta2**self.steps).sqrt()
        step_size = (self.lr / bias1).to(self.params.dtype).to(self.params.device).unsqueeze(1)
        denom = (self.exp_avg_sq.sqrt() / bias2_sqrt.to(self.params.dtype).to(g.device).unsqueeze(1)).add_(self.eps)
        self.params.sub_(step_size * self.exp_avg / denom)
        if active is not None:
            for now, before in zip((self.params, self.exp_avg, self.exp_avg_sq), old):
                now.copy_(torch.where(keep, before, now))

    def zero_grad(self) -> None:
        self.params.grad = None


def linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``nn.Linear`` for every agent at once: ``x [P, B, in]``, ``weight [P, out, in]``, ``bias [P, out]``."""
    return torch.baddbmm(bias.unsqueeze(1), x, weight.transpose(1, 2))


def sequential(net: nn.Sequential, prefix: str, stacked: StackedParams, x: torch.Tensor) -> torch.Tensor:
    """The single-run ``nn.Sequential`` ``net`` (Linear and activation modules, the MLP of
    ``policies/mlp.py``) applied per agent with the stacked parameters named ``prefix.<i>.*``."""
    for i, module in enumerate(net):
        if isinstance(module, nn.Linear):
            x = linear(x, stacked.view(f"{prefix}.{i}.weight"), stacked.view(f"{prefix}.{i}.bias"))
        else:  # elementwise activation: any leading dimensions
            x = module(x)
    return x


def template(agent: Agent) -> tuple[nn.Sequential, dict[str, nn.Sequential]]:
    """The actor's and critics' output networks of a single-run MLP agent (their architecture)."""
    return agent.actor.head.net, {s: c.net for s, c in agent.critics.items()}


__all__ = ["StackedAdam", "StackedParams", "linear", "sequential", "template"]
