"""Critic regression, shared by every algorithm: both critics fit their GAE value targets
(lambda-returns) by mean squared error."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from cmdp_rl import keys
from cmdp_rl.policies import ActorCritic


def critic_losses(ac: ActorCritic, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
    """MSE of the reward critic and of the cost critic on ``batch``'s value targets."""
    obs = batch.select(keys.OBS)
    v = ac.critic(obs).get(keys.VALUE)
    vc = ac.cost_critic(obs).get(keys.COST_VALUE)
    loss_v = (v - batch.get(keys.VALUE_TARGET)).pow(2).mean()
    loss_vc = (vc - batch.get(keys.COST_VALUE_TARGET)).pow(2).mean()
    return loss_v, loss_vc
