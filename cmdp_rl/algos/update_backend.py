"""How a PPO-family update reaches its networks: the iteration (:func:`iterate`) and its minibatch
epochs written once, over one agent's training units ``[U, ...]`` (:class:`OneAgent`) or P agents'
``[P, U, ...]`` side by side (``population/update.PopulationPPO``: each network a row of stacked
parameters).

The backend owns what differs: the order of each epoch (torch's global generator for one agent,
each agent's own generator for P), the reduction of a per-unit loss (``torch.mean``, or the mean
over each agent's rows), the forward pass, gradient-norm clipping and the optimiser (torch's fused
Adam for one agent, ``population/params.StackedAdam`` for P), and KL early stopping, which is a
mask over the agents: an agent past its limit is evaluated on that minibatch, takes no step and
draws no further permutation, as a single run breaks out of its loop; with one agent the loop ends
there. The algorithm owns the minibatch's losses (``PPO.minibatch_step``, CUP's stage 2) and each
member's own arithmetic around them (``prepare``, ``finish``).
"""

from __future__ import annotations

import inspect
from functools import partial
from typing import Any, Callable, Protocol, Sequence

import torch
from tensordict import TensorDictBase
from torch import distributions as D

from cmdp_rl.algos.base import TrainingDiverged, check_parameters_finite
from cmdp_rl.rollout import keys

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

    def critic_values(self, mb: Units) -> dict[str, torch.Tensor] | None:
        """The critics' values by signal on a minibatch (None: ``CriticRegression`` computes them)."""

    def stop(self, kl: torch.Tensor, active: Any) -> tuple[Any, Any]:
        """KL early stopping: the agents still active after this minibatch, and those that step on it."""

    def step(self, loss: torch.Tensor, groups: Sequence[Group], stepping: Any) -> None:
        """Backward, clip and step the ``stepping`` agents' parameters."""

    def kept(self, stats: dict[str, torch.Tensor], evaluated: Any) -> dict[str, torch.Tensor]:
        """The statistics detached, zero for an agent that did not evaluate this minibatch."""

    def count(self, evaluated: Any) -> Any: ...

    # --- around the epochs: what an iteration asks of the members' networks and optimisers
    def set_rates(self, algos: Sequence[Any]) -> None:
        """Each member's learning rates this iteration (``anneal_lr``)."""

    def groups(self, algos: Sequence[Any]) -> list[Group]:
        """The actor's and the critics' optimiser and parameters."""

    def fresh_actor_groups(self, algos: Sequence[Any]) -> list[Group]:
        """A fresh Adam on the actors at each member's actor rate (CUP's stage 2)."""

    def training_units(self, data: Units) -> Units:
        """The members' ``[N, T, ...]`` rows as training units."""

    def actor_params(self, units: Units) -> dict[str, torch.Tensor]:
        """The actor's distribution parameters on training units."""

    def per_member(self, values: Sequence[float]) -> Any:
        """One number per member, as the losses weigh a unit by it."""

    def check_finite(self) -> None:
        """Stop (:class:`TrainingDiverged`) on a parameter that is not finite."""


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


def members(batch: TensorDictBase, count: int) -> list[TensorDictBase]:
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


def iterate(algos: Sequence[Any], batch: TensorDictBase, backend: Any) -> list[dict[str, float]]:
    """One PPO-family iteration of every member on ``batch`` (a run: one algorithm and
    :class:`OneAgent`; a population: each agent's own algorithm object and the stacked backend):
    the learning rates, GAE, each member's ``prepare`` on its rows, the minibatch epochs (the first
    algorithm's ``minibatch_step``), the algorithm's ``second_stage`` (CUP's), each member's
    ``finish``. Returns each member's statistics."""
    first, cfg = algos[0], algos[0].cfg
    if cfg.anneal_lr:
        backend.set_rates(algos)
    first.gae(batch, backend.agent)  # along time, row by row: every member's rows at once
    rows = members(batch, len(algos))
    batch.set(keys.POLICY_ADVANTAGE, joined([a.prepare(r) for a, r in zip(algos, rows)]))
    # Only what the minibatch loop reads, as training units: a run's steps [N*T, ...] (or a
    # recurrent policy's segments, Agent.training_units), a population's [P, N*T, ...].
    data = backend.training_units({k: batch.get(k) for k in first._update_keys(batch)})
    step = partial(first.minibatch_step, backend, backend.groups(algos))
    sums, counts = run_epochs(backend, data, cfg.num_minibatches, cfg.update_epochs, step)
    means = {k: v / counts for k, v in sums.items()}  # each member's mean over its minibatches
    means.update(first.second_stage(backend, algos, rows))
    # One host sync per update (not per minibatch): read the statistics, stop on NaN/inf.
    values = torch.stack(list(means.values())).reshape(len(means), len(algos)).tolist()
    out = []
    for i, a in enumerate(algos):
        try:
            out.append(a.finish({k: values[s][i] for s, k in enumerate(means)}))
        except TrainingDiverged as exc:
            if len(algos) == 1:
                raise
            raise TrainingDiverged(f"agent {i}: {exc}") from exc
    backend.check_finite()
    return out


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

    def critic_values(self, mb: Units) -> None:
        return None  # CriticRegression.losses computes them

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

    def set_rates(self, algos: Sequence[Any]) -> None:
        a = algos[0]
        a.actor_opt.param_groups[0]["lr"], a.critic_opt.param_groups[0]["lr"] = a.learning_rates()

    def groups(self, algos: Sequence[Any]) -> list[Group]:
        a = algos[0]
        return [(a.actor_opt, a.actor_params), (a.critic_opt, a.critic_params)]

    def fresh_actor_groups(self, algos: Sequence[Any]) -> list[Group]:
        a = algos[0]
        return [(torch.optim.Adam(a.actor_params, lr=a.actor_opt.param_groups[0]["lr"], fused=True), a.actor_params)]

    def training_units(self, data: Units) -> Units:
        return self.agent.training_units(data)

    def actor_params(self, units: Units) -> dict[str, torch.Tensor]:
        return self.agent.actor.params(units)

    def per_member(self, values: Sequence[float]) -> float:
        return values[0]

    def check_finite(self) -> None:
        check_parameters_finite(self.agent)


__all__ = ["Backend", "OneAgent", "iterate", "joined", "members", "run_epochs"]
