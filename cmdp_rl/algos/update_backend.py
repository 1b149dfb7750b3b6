"""How a PPO-family update reaches its networks: the minibatch epochs written once, over one agent's
training units ``[U, ...]`` (:class:`OneAgent`) or P agents' ``[P, U, ...]`` side by side
(``population/update.StackedAgents``: each network a row of stacked parameters).

The backend owns what differs: the order of each epoch (torch's global generator for one agent,
each agent's own generator for P), the reduction of a per-unit loss (``torch.mean``, or the mean
over each agent's rows), the forward pass, gradient-norm clipping and the optimiser (torch's fused
Adam for one agent, ``population/params.StackedAdam`` for P), and KL early stopping, which is a
mask over the agents: an agent past its limit is evaluated on that minibatch, takes no step and
draws no further permutation, as a single run breaks out of its loop; with one agent the loop ends
there. The algorithm owns the minibatch's losses (``PPO.minibatch_step``, CUP's stage 2).
"""

from __future__ import annotations

import inspect
from typing import Any, Callable, Protocol, Sequence

import torch
from torch import distributions as D

Units = dict[Any, torch.Tensor]
# An optimiser and the parameters it steps: torch's Adam and a parameter list, or StackedAdam and
# the StackedParams it steps.
Group = tuple[Any, Any]


class Backend(Protocol):
    def start(self) -> Any:
        """Which agents are active before the first minibatch (all)."""

    def any_active(self, active: Any) -> bool: ...

    def shuffle(self, data: Units, active: Any) -> Units:
        """One epoch's order of ``data``, drawn for the active agents."""

    def minibatch(self, shuffled: Units, start: int, stop: int) -> Units: ...

    def units(self, data: Units) -> int:
        """The training units per agent."""

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """A per-unit quantity's mean (per agent)."""

    def dist(self, mb: Units) -> D.Distribution:
        """The actor's distribution on a minibatch."""

    def training_pass(self, mb: Units) -> tuple[D.Distribution, dict[str, torch.Tensor] | None]:
        """The actor's distribution and, where computed together, the critics' values by signal."""

    def stop(self, kl: torch.Tensor, active: Any) -> tuple[Any, Any]:
        """KL early stopping: the agents still active after this minibatch, and those that step on it."""

    def step(self, loss: torch.Tensor, groups: Sequence[Group], stepping: Any) -> None:
        """Backward, clip and step the ``stepping`` agents' parameters."""

    def kept(self, stats: dict[str, torch.Tensor], evaluated: Any) -> dict[str, torch.Tensor]:
        """The statistics detached, zero for an agent that did not evaluate this minibatch."""

    def count(self, evaluated: Any) -> Any: ...


Step = Callable[[Units, Any], tuple[dict[str, torch.Tensor], Any]]


@torch.no_grad()
def clip_grad_norm_(params: Sequence[torch.Tensor], max_norm: float) -> None:
    """``torch.nn.utils.clip_grad_norm_`` for parameters of one device and dtype, in its arithmetic
    (per-tensor norms, their 2-norm, the coefficient ``max_norm / (norm + 1e-6)`` clamped at 1):
    torch's groups the gradients by device and dtype on every call, and at 64 minibatch steps an
    iteration of two networks that bookkeeping was about a tenth of the update's CPU time
    (docs/throughput.md)."""
    grads = [p.grad for p in params if p.grad is not None]
    if grads:
        total = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads, 2.0)), 2.0)
        torch._foreach_mul_(grads, torch.clamp(max_norm / (total + 1e-6), max=1.0))


# Torch's Adam.step, seen through the profiling wrapper torch puts on it when an optimiser is built.
_TORCH_ADAM_STEP = inspect.unwrap(torch.optim.Adam.step)


def adam_step(opt: torch.optim.Optimizer) -> None:
    """``opt.step()``; for a fused Adam with one parameter group and default options, the same
    kernel on the same tensors called directly: ``Optimizer.step``'s wrappers (hooks, profiler
    records, the state scan, grouping by device and dtype) cost about twice the kernel itself on
    these small networks, 64 times an iteration (docs/throughput.md)."""
    groups = opt.param_groups
    g = groups[0]
    if not (
        type(opt) is torch.optim.Adam
        and inspect.unwrap(torch.optim.Adam.step) is _TORCH_ADAM_STEP  # a patched step (a test's) is honoured
        and len(groups) == 1
        and g["fused"]
        and not (g["amsgrad"] or g["maximize"] or g["capturable"] or g["differentiable"] or g["weight_decay"])
    ):
        return opt.step()
    params = [p for p in g["params"] if p.grad is not None]
    states = [opt.state.get(p) for p in params]
    if not params or not all(states):  # the first step creates the moments: torch's own code
        return opt.step()
    steps = [st["step"] for st in states]
    torch._foreach_add_(steps, 1)
    torch._fused_adam_(
        params,
        [p.grad for p in params],
        [st["exp_avg"] for st in states],
        [st["exp_avg_sq"] for st in states],
        [],
        steps,
        amsgrad=False,
        lr=g["lr"],
        beta1=g["betas"][0],
        beta2=g["betas"][1],
        weight_decay=0.0,
        eps=g["eps"],
        maximize=False,
        grad_scale=None,
        found_inf=None,
    )


def run_epochs(backend: Backend, data: Units, num_minibatches: int, epochs: int, step: Step) -> tuple[dict, Any]:
    """``epochs`` passes over ``data``, each in a fresh order, split into ``num_minibatches`` equal
    slices (units left over by the division are skipped in that pass); ``step(minibatch, active)
    -> (stats, active)`` on each. Returns the statistics summed over the minibatches each agent
    evaluated, and how many it evaluated."""
    total = backend.units(data)
    size = total // num_minibatches
    if size < 1:
        raise ValueError(f"{num_minibatches} minibatches of {total} units: at most {total} allowed")
    active = backend.start()
    sums: dict[str, torch.Tensor] = {}
    counts: Any = 0
    for _ in range(epochs):
        if not backend.any_active(active):
            break
        shuffled = backend.shuffle(data, active)
        for j in range(num_minibatches):
            evaluated = active
            stats, active = step(backend.minibatch(shuffled, j * size, (j + 1) * size), active)
            sums = {k: sums[k] + v if k in sums else v for k, v in stats.items()}
            counts = counts + backend.count(evaluated)
            if not backend.any_active(active):
                break
    return sums, counts


class OneAgent:
    """One agent's update: ``kl_limit`` None never stops; ``entropy_coef`` None is the algorithm's."""

    entropy_coef = None

    def __init__(self, agent: Any, max_grad_norm: float, kl_limit: float | None) -> None:
        self.agent, self.max_grad_norm, self.kl_limit = agent, max_grad_norm, kl_limit

    def start(self) -> bool:
        return True

    def any_active(self, active: bool) -> bool:
        return active

    def units(self, data: Units) -> int:
        return next(iter(data.values())).shape[0]

    def shuffle(self, data: Units, active: bool) -> Units:
        perm = torch.randperm(self.units(data), device=next(iter(data.values())).device)
        return {k: v[perm] for k, v in data.items()}  # one gather per pass; each minibatch a view

    def minibatch(self, shuffled: Units, start: int, stop: int) -> Units:
        return {k: v[start:stop] for k, v in shuffled.items()}

    mean = staticmethod(torch.mean)

    def dist(self, mb: Units) -> D.Distribution:
        return self.agent.dist(mb)

    def training_pass(self, mb: Units) -> tuple[D.Distribution, None]:
        return self.agent.dist(mb), None  # the critics' values: CriticRegression.losses computes them

    def stop(self, kl: torch.Tensor, active: bool) -> tuple[bool, bool]:
        go = self.kl_limit is None or not kl.item() > self.kl_limit
        return go, go

    def step(self, loss: torch.Tensor, groups: Sequence[Group], stepping: bool) -> None:
        if not stepping:  # KL early stopping: this minibatch's step would leave the trust region
            return
        for _, params in groups:
            for p in params:  # optimizer.zero_grad(set_to_none=True), without its per-call wrappers
                p.grad = None
        # One backward pass: the losses have disjoint parameters, so each network's gradient is that
        # of its own loss.
        loss.backward()
        for _, params in groups:
            clip_grad_norm_(params, self.max_grad_norm)
        for opt, _ in groups:
            adam_step(opt)

    def kept(self, stats: dict[str, torch.Tensor], evaluated: bool) -> dict[str, torch.Tensor]:
        return {k: v.detach() for k, v in stats.items()}

    def count(self, evaluated: bool) -> int:
        return 1


__all__ = ["Backend", "OneAgent", "run_epochs"]
