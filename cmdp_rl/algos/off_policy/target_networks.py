"""Target networks and one-step TD targets of the off-policy algorithms (SAC, TD3): slow copies
moved by Polyak averaging, so that a critic regresses on a target that does not chase itself."""

from __future__ import annotations

import copy

import torch
from torch import nn


class TargetCritics:
    """Slow copies of critics' output networks (the body is shared: it has no parameters, and the
    copy reads the live observation statistics), moved by Polyak averaging."""

    def __init__(self, modules: dict[str, nn.Module]) -> None:
        self.live = modules
        self.target = {k: copy.deepcopy(m).requires_grad_(False) for k, m in modules.items()}
        # Listed once (load_state_dict copies into these tensors): one lerp over all of them a step.
        self._pairs = (
            [p for k in modules for p in self.target[k].parameters()],
            [p for m in modules.values() for p in m.parameters()],
        )

    @torch.no_grad()
    def soft_update(self, tau: float) -> None:
        """``theta' <- tau theta + (1 - tau) theta'`` (Haarnoja et al. 2018b; Fujimoto et al. 2018)."""
        torch._foreach_lerp_(*self._pairs, tau)

    def state_dict(self) -> dict:
        return {k: m.state_dict() for k, m in self.target.items()}

    def load_state_dict(self, state: dict) -> None:
        for k, m in self.target.items():
            m.load_state_dict(state[k])


def td_target(signal: torch.Tensor, terminated: torch.Tensor, gamma: float, next_value: torch.Tensor) -> torch.Tensor:
    """One-step TD target ``x + gamma (1 - terminated) V'``: a truncated step bootstraps from its
    final observation; only termination stops the sum."""
    return signal + gamma * (~terminated).float() * next_value
