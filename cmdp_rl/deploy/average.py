"""The deployed policy of ``deploy.policy: average``: the uniform (Polyak-Ruppert) average of the
actor's parameters over the last ``deploy.window`` fraction of the training iterations.

Why an average at all: a Lagrangian method's guarantees are for the average of its iterates
(the policy and lambda orbit the saddle point; the last iterate is wherever the orbit ends). Why
of the parameters, rather than a mixture of the last M actors with one drawn per episode (whose
occupancy measure is exactly the average of theirs): the average is one network of the same
architecture, so every consumer of a trained agent (the evaluation, evaluate.py, the Reach1D plot,
the video, a deterministic evaluation, a recurrent policy's carried state) runs it unchanged, and
the checkpoint grows by one actor instead of M. The price: near a randomised optimum the iterates
differ mostly in the few logits that pick between the mixed actions, and averaging those logits
gives a policy between the iterates' choices, not their exact mixture (docs/constraint_satisfaction.md
measures how close it ends). Buffers (none in the toolkit's actors today) are the last iterate's.
"""

from __future__ import annotations

import math

import torch
from torch import nn


def first_averaged_iteration(iterations: int, window: float) -> int:
    """The first of the last ``ceil(window * iterations)`` iterations (1-based; at least the last)."""
    return iterations - max(1, math.ceil(window * iterations)) + 1


def deployed(result: dict) -> str:
    """Which policy an evaluation ran, from its ``final_policy`` (the run's ``deploy.policy``),
    ``averaged_iterations`` and ``mixture_iterations`` keys (a result from before they existed: the last iterate)."""
    if result.get("final_policy") == "mixture" and result.get("mixture_deployed"):
        chosen = ", ".join(f"iteration {int(it)} ({w:.2f})" for it, w in result["mixture_deployed"])
        margin = f", costs + {result['mixture_margin']:g} standard errors" if "mixture_margin" in result else ""
        within = (
            f"within budget on their values{margin}"
            if result.get("mixture_feasible")
            else "none within budget: the least violating"
        )
        if len(result["mixture_deployed"]) == 1:
            which = (
                f"the best within budget{margin}"
                if result.get("mixture_feasible")
                else "none within budget: the least violating"
            )
            return (
                f"deployed policy: iteration {int(result['mixture_deployed'][0][0])}'s actor, of "
                f"{result.get('averaged_iterations')} snapshots valued ({which} on their values)"
            )
        return (
            f"deployed policy: a weighted mixture of {result.get('averaged_iterations')} iterates' actors "
            f"({within}): {chosen}, one drawn per episode"
        )
    if result.get("final_policy") == "mixture":
        return (
            f"deployed policy: a uniform mixture of {result.get('averaged_iterations')} iterates' actors "
            f"(iterations {result.get('mixture_iterations')}), one drawn per episode"
        )
    if result.get("final_policy", "last") == "average":
        return f"deployed policy: the average of the last {result.get('averaged_iterations')} iterates' parameters"
    return "deployed policy: the last iterate"


class ParameterAverage:
    """Running mean of a module's parameters, one sample per :meth:`update`. Its state holds plain
    tensors and an int, so a checkpoint with it loads with ``torch.load(weights_only=True)``."""

    def __init__(self) -> None:
        self.count = 0
        self.mean: dict[str, torch.Tensor] = {}

    @torch.no_grad()
    def update(self, module: nn.Module) -> None:
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

    def state_dict(self) -> dict:
        return {"count": self.count, "mean": {k: v.clone() for k, v in self.mean.items()}}

    def load_state_dict(self, state: dict) -> None:
        self.count = int(state["count"])
        self.mean = {k: v.clone() for k, v in state["mean"].items()}
