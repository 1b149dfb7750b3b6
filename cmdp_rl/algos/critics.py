"""Critic regression, shared by every algorithm: both critics fit their GAE value targets
(lambda-returns) by mean squared error."""

from __future__ import annotations

import torch

from cmdp_rl import keys
from cmdp_rl.policies import ActorCritic
from cmdp_rl.policies.tensor_path import TensorModule


class CriticRegression:
    """MSE of the reward critic and of the cost critic on a minibatch's value targets.

    A minibatch is a dict of tensors (root keys) over training units: steps, or for recurrent
    critics segments (``ActorCritic.training_units``). The critics run on their tensor paths where
    the modules allow (``policies/tensor_path.py``: same numbers, without TensorDict overhead), else
    as TensorDict modules, in the mode the ActorCritic says.
    """

    def __init__(self, ac: ActorCritic) -> None:
        self.ac = ac
        self.fast = TensorModule.wrap(ac.critic)
        self.cost_fast = TensorModule.wrap(ac.cost_critic)

    def losses(self, mb: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        v = self._values(mb, self.fast, self.ac.critic, keys.VALUE)
        vc = self._values(mb, self.cost_fast, self.ac.cost_critic, keys.COST_VALUE)
        return (v - mb[keys.VALUE_TARGET]).pow(2).mean(), (vc - mb[keys.COST_VALUE_TARGET]).pow(2).mean()

    def _values(self, mb: dict[str, torch.Tensor], fast: TensorModule | None, module, key: str) -> torch.Tensor:
        if fast is not None:
            return fast(mb)
        with self.ac.sequence_mode():  # recurrent critics: [B, L] segments in recurrent mode
            return module(self.ac.units_tensordict(mb)).get(key)
