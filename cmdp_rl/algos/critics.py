"""Critic regression, shared by every algorithm: each critic fits its GAE value targets
(lambda-returns) by mean squared error."""

from __future__ import annotations

from typing import Callable

import torch

from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys

# The statistic each critic's loss is logged as.
LOSS_NAMES = {"reward": "loss_v", "cost": "loss_vc"}


class CriticRegression:
    """MSE of every critic of the agent on a minibatch's value targets.

    A minibatch is a dict of tensors (root keys) over training units: steps, or for recurrent
    critics segments (``Agent.training_units``).
    """

    def __init__(self, agent: Agent) -> None:
        self.agent = agent

    def losses(
        self,
        mb: dict[str, torch.Tensor],
        values: dict[str, torch.Tensor] | None = None,
        mean: Callable[[torch.Tensor], torch.Tensor] = torch.mean,
    ) -> dict[str, torch.Tensor]:
        """``{"loss_v": ..., "loss_vc": ...}``: one loss per critic. A population passes its agents'
        ``values`` by signal on ``[P, B, ...]`` and its per-agent ``mean``."""
        out = {}
        for signal in self.agent.critics:
            target = mb[keys.SIGNALS[signal][3]]
            value = self.agent.value(signal, mb) if values is None else values[signal]
            out[LOSS_NAMES[signal]] = mean((value - target).pow(2))
        return out

    def target_keys(self) -> list[str]:
        """The value targets a minibatch must carry."""
        return [keys.SIGNALS[signal][3] for signal in self.agent.critics]
