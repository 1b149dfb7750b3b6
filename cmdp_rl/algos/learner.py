"""What an update loop asks of the networks it trains (:class:`Learner`): their forward pass, the reduction of
per-sample losses, each epoch's minibatch order and the optimiser step. ``ppo.ppo_update``, CUP's projection and the
trust-region critic regression are written against it once; a run's one agent answers it (:class:`SingleLearner`:
``torch.mean``, one backward pass, torch's fused Adam), and P stacked agents do (``population.learner.StackedLearner``:
a mean per agent, StackedAdam on each agent's rows). ``tests/test_protocols.py`` checks both with mypy."""

from __future__ import annotations

from typing import Any, Iterator, Protocol, Sequence

import torch
from torch import distributions as D
from torch.optim.adam import adam as functional_adam

from cmdp_rl.algos.minibatch import minibatches
from cmdp_rl.policies.agent import Agent

Units = dict[str, torch.Tensor]
# An optimiser and the parameters it steps (a run's network; a population's stacked rows).
Optimiser = tuple[Any, Any]


class Learner(Protocol):
    """The networks an update loop trains, for one member or several side by side (their statistics then one
    number per member). ``agent`` acts, values and cuts the batch into training units as an ``Agent`` does."""

    agent: Any

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """Each member's mean of the per-sample ``x``."""
        ...

    def per_member(self, values: Sequence[Any]) -> Any:
        """One number per member, in the shape :meth:`mean` gives."""
        ...

    def minibatches(self, units: Units, num_minibatches: int, active: Any = True) -> Iterator[Units]:
        """One pass over the units in a fresh order; members no longer ``active`` (KL stopping) draw none."""
        ...

    def forward(self, mb: Units) -> tuple[D.Distribution, Units]:
        """The actor's distribution and the critics' values by signal."""
        ...

    def dist(self, mb: Units) -> D.Distribution: ...

    def values(self, mb: Units) -> Units: ...

    def actor_params(self, units: Units) -> Units:
        """The actor's distribution parameters (CUP's pi_{k+1/2})."""
        ...

    def optimisers(self, algos: Sequence[Any]) -> list[Any]:
        """The actor's and the critics' optimiser, each with the parameters it steps."""
        ...

    def fresh_actor_optimiser(self, algos: Sequence[Any]) -> list[Any]:
        """Adam on the actor with no moments yet, at the actor's rate this iteration (CUP's stage 2)."""
        ...

    def step(self, loss: torch.Tensor, optimisers: Sequence[Any], stepping: Any = True) -> None:
        """Backward, clip and step the members ``stepping`` holds (True: all)."""
        ...


class SingleLearner:
    """A run's reducer (``torch.mean``) and optimiser step; ``population.learner.StackedLearner`` is P agents'."""

    mean = staticmethod(torch.mean)

    def __init__(self, agent: Agent, max_grad_norm: float) -> None:
        self.agent, self.max_grad_norm = agent, max_grad_norm

    @staticmethod
    def per_member(values: Sequence[Any]) -> Any:
        """One number per member (a run's one)."""
        return values[0]

    def minibatches(self, units: Units, num_minibatches: int, active: Any = True) -> Iterator[Units]:
        """One pass over the units in a fresh order (torch's global generator, as a seeded run repeats)."""
        return (mb for _, mb in minibatches(units, num_minibatches))

    def forward(self, mb: Units) -> tuple[D.Distribution, Units]:
        """The actor's distribution and the critics' values by signal."""
        return self.agent.dist(mb), self.values(mb)

    def dist(self, mb: Units) -> D.Distribution:
        return self.agent.dist(mb)

    def values(self, mb: Units) -> Units:
        return {signal: self.agent.value(signal, mb) for signal in self.agent.critics}

    def actor_params(self, units: Units) -> Units:
        """The actor's distribution parameters (CUP's pi_{k+1/2})."""
        return self.agent.actor.params(units)

    def optimisers(self, algos: Sequence[Any]) -> list[Optimiser]:
        a = algos[0]
        return [(a.actor_opt, a.actor_params), (a.critic_opt, a.critic_params)]

    def fresh_actor_optimiser(self, algos: Sequence[Any]) -> list[Optimiser]:
        """Adam on the actor with no moments yet, at the actor's rate this iteration (CUP's stage 2)."""
        a = algos[0]
        return [(torch.optim.Adam(a.actor_params, lr=a.actor_opt.param_groups[0]["lr"], fused=True), a.actor_params)]

    def step(self, loss: torch.Tensor, optimisers: Sequence[Optimiser], stepping: Any = True) -> None:
        """Backward, clip each network's gradient norm, step its Adam; nothing once ``stepping`` is false."""
        if not stepping:
            return
        for _, params in optimisers:
            for p in params:  # optimizer.zero_grad(set_to_none=True), without its per-call profiling
                p.grad = None
        loss.backward()  # one pass: the networks share no parameter
        for _, params in optimisers:
            clip_grad_norm_(params, self.max_grad_norm)
        for opt, _ in optimisers:
            adam_step(opt)


def adam_step(opt: torch.optim.Optimizer) -> None:
    """``opt.step()``; for torch's fused Adam with one parameter group, default options and its moments
    created, the same kernel through torch's functional ``torch.optim.adam.adam``: ``Optimizer.step``'s
    wrappers cost more than the kernel on small networks (docs/throughput.md; tests/test_update_loop.py
    checks the two bit for bit)."""
    group, params = opt.param_groups[0], opt.param_groups[0]["params"]
    options = ("amsgrad", "maximize", "weight_decay", "capturable", "differentiable", "decoupled_weight_decay")
    plain = type(opt) is torch.optim.Adam and len(opt.param_groups) == 1 and not any(group.get(k) for k in options)
    if not (plain and group["fused"] and len(opt.state) == len(params) and all(p.grad is not None for p in params)):
        opt.step()
        return
    states = [opt.state[p] for p in params]
    beta1, beta2 = group["betas"]
    with torch.no_grad():
        functional_adam(
            params,
            [p.grad for p in params],
            [s["exp_avg"] for s in states],
            [s["exp_avg_sq"] for s in states],
            [],
            [s["step"] for s in states],
            fused=True,
            amsgrad=False,
            beta1=beta1,
            beta2=beta2,
            lr=group["lr"],
            weight_decay=0.0,
            eps=group["eps"],
            maximize=False,
        )


@torch.no_grad()
def clip_grad_norm_(params: Sequence[torch.Tensor], max_norm: float) -> None:
    """``torch.nn.utils.clip_grad_norm_``'s arithmetic without its per-call grouping (docs/throughput.md)."""
    grads = [p.grad for p in params if p.grad is not None]
    if grads:
        total = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads, 2.0)), 2.0)
        torch._foreach_mul_(grads, torch.clamp(max_norm / (total + 1e-6), max=1.0))
