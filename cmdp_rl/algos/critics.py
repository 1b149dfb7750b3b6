"""Critic regression, shared by every algorithm: each critic fits its GAE value targets
(lambda-returns) by squared error, ``L^VF = (V(s) - V^targ)^2`` (Schulman et al. 2017, eq. 9)."""

from __future__ import annotations

import torch

from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys

# The statistic each critic's loss is logged as.
LOSS_NAMES = {"reward": "loss_v", "cost": "loss_vc"}


class CriticRegression:
    """The squared error of every critic of the agent on a minibatch of training units' value targets."""

    def __init__(self, agent: Agent) -> None:
        self.agent = agent

    def terms(
        self, mb: dict[str, torch.Tensor], values: dict[str, torch.Tensor] | None = None
    ) -> dict[str, torch.Tensor]:
        """``{"loss_v": ..., "loss_vc": ...}``: each critic's loss per sample, for the caller to reduce;
        ``values``: the critics' values by signal where the caller computed them, else the agent's."""
        out = {}
        for signal in self.agent.critics:
            target = mb[keys.SIGNALS[signal][3]]
            value = self.agent.value(signal, mb) if values is None else values[signal]
            out[LOSS_NAMES[signal]] = (value - target).pow(2)
        return out

    def losses(self, mb: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Each critic's mean squared error on the minibatch."""
        return {name: terms.mean() for name, terms in self.terms(mb).items()}

    def target_keys(self) -> list[str]:
        """The value targets a minibatch must carry."""
        return [keys.SIGNALS[signal][3] for signal in self.agent.critics]
