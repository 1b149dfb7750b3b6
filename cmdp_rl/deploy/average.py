"""The deployed policy of ``deploy.policy: average``: the uniform (Polyak-Ruppert) average of the actor's
parameters over the last ``deploy.window`` of the iterations: one network any consumer runs unchanged, but near a
randomised optimum a policy between the iterates' choices, not their mixture (docs/constraint_satisfaction.md)."""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn


def first_averaged_iteration(iterations: int, window: float) -> int:
    """The first of the last ``ceil(window * iterations)`` iterations (1-based; at least the last)."""
    return iterations - max(1, math.ceil(window * iterations)) + 1


def deployed(result: dict) -> str:
    """Which policy an evaluation ran, from its ``final_policy`` and ``averaged_iterations`` and ``mixture_*`` keys."""
    policy, n = result.get("final_policy", "last"), result.get("averaged_iterations")
    chosen = result.get("mixture_deployed") if policy == "mixture" else None
    if chosen:
        margin = f", costs + {result['mixture_margin']:g} standard errors" if "mixture_margin" in result else ""
        feasible = result.get("mixture_feasible")
        if len(chosen) == 1:
            which = f"the best within budget{margin}" if feasible else "none within budget: the least violating"
            which = f"{n} snapshots valued ({which} on their values)"
            return f"deployed policy: iteration {int(chosen[0][0])}'s actor, of {which}"
        within = f"within budget on their values{margin}" if feasible else "none within budget: the least violating"
        pairs = ", ".join(f"iteration {int(it)} ({w:.2f})" for it, w in chosen)
        return f"deployed policy: a weighted mixture of {n} iterates' actors ({within}): {pairs}, one drawn per episode"
    if policy == "mixture":
        iterations = f"iterations {result.get('mixture_iterations')}"
        return f"deployed policy: a uniform mixture of {n} iterates' actors ({iterations}), one drawn per episode"
    if policy == "average":
        return f"deployed policy: the average of the last {n} iterates' parameters"
    return "deployed policy: the last iterate"


class ParameterAverage:
    """Running mean of a module's parameters, one sample per :meth:`update` (plain tensors and an int)."""

    def __init__(self, first_iteration: int = 1) -> None:
        self.first_iteration, self.count = first_iteration, 0
        self.mean: dict[str, torch.Tensor] = {}

    def wants(self, iteration: int) -> bool:
        return iteration >= self.first_iteration

    @torch.no_grad()
    def update(self, module: nn.Module, iteration: int | None = None) -> None:
        self.count += 1
        for name, p in module.named_parameters():
            if name not in self.mean:
                self.mean[name] = p.detach().clone()
            else:
                self.mean[name].add_(p.detach() - self.mean[name], alpha=1.0 / self.count)

    @torch.no_grad()
    def apply(self, module: nn.Module) -> None:
        """Overwrite ``module``'s parameters with the average (nothing when no sample was taken)."""
        for name, p in module.named_parameters():
            if name in self.mean:
                p.copy_(self.mean[name])

    def deploy(self, agent: Any) -> None:
        self.apply(agent.actor)

    def state_dict(self) -> dict:
        mean = {k: v.clone() for k, v in self.mean.items()}
        return {"first_iteration": self.first_iteration, "count": self.count, "mean": mean}

    def load_state_dict(self, state: dict) -> None:
        self.count = int(state["count"])
        self.mean = {k: v.clone() for k, v in state["mean"].items()}
