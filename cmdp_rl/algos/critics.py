"""Critic regression, shared by every algorithm: each critic fits its GAE value targets
(lambda-returns) by mean squared error."""

from __future__ import annotations

import torch

from cmdp_rl import keys
from cmdp_rl.policies.agent import Agent

# The statistic each critic's loss is logged as.
LOSS_NAMES = {"reward": "loss_v", "cost": "loss_vc"}


class CriticRegression:
    """MSE of every critic of the agent on a minibatch's value targets.

    A minibatch is a dict of tensors (root keys) over training units: steps, or for recurrent
    critics segments (``Agent.training_units``).
    """

    def __init__(self, agent: Agent) -> None:
        self.agent = agent

    def losses(self, mb: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """``{"loss_v": ..., "loss_vc": ...}``: one loss per critic."""
        out = {}
        for signal in self.agent.critics:
            target = mb[keys.SIGNALS[signal][3]]
            out[LOSS_NAMES[signal]] = (self.agent.value(signal, mb) - target).pow(2).mean()
        return out

    def target_keys(self) -> list[str]:
        """The value targets a minibatch must carry."""
        return [keys.SIGNALS[signal][3] for signal in self.agent.critics]
