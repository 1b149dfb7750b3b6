"""What a policy network reads: the observation and, optionally, the previous action and cost.

A POMDP policy should act on its history (o_0..o_t, a_0..a_{t-1}); the previous action and cost
are the parts of that history the observation lacks. The collector writes them at the root
(``keys.PREV_ACTION``, ``keys.PREV_COST``; zero on an episode's first step) for any policy whose
``in_keys`` ask for them, so a memory policy can integrate its own motion (dead reckoning) and
notice when it paid a cost. Feeding the previous cost to a recurrent policy follows the
PID-Lagrangian experiments (Stooke, Achiam, Abbeel, 2020, "Responsive Safety in Reinforcement
Learning by PID Lagrangian Methods", sec. 6).
"""

from __future__ import annotations

import torch
from torch import nn

from cmdp_rl import keys


def input_keys(include_prev_action: bool, include_prev_cost: bool) -> list[str]:
    """The root entries a network reads, in the order :class:`InputEncoder` takes them."""
    return [keys.OBS] + ([keys.PREV_ACTION] if include_prev_action else []) + ([keys.PREV_COST] if include_prev_cost else [])


class InputEncoder(nn.Module):
    """``cat(normalized obs, previous action in box units, previous cost vector [K])``.

    The previous action is mapped to the action box as ``[-1, 1]`` and clipped there, as the env
    clips it: what the policy sees is the command the env executed. ``obs_norm`` (a running
    normalizer, normalization.py) is applied to the observation only.
    """

    def __init__(
        self,
        obs_dim: int,
        low: torch.Tensor,
        high: torch.Tensor,
        include_prev_action: bool,
        include_prev_cost: bool,
        obs_norm: nn.Module | None = None,
        num_costs: int = 1,
    ) -> None:
        super().__init__()
        self.obs_norm = obs_norm
        self.include_prev_action = include_prev_action
        self.include_prev_cost = include_prev_cost
        self.num_costs = num_costs  # the previous cost is the vector of the env's K costs
        self.register_buffer("center", (high + low) / 2)
        self.register_buffer("half_width", (high - low) / 2)
        self.out_dim = obs_dim + (low.numel() if include_prev_action else 0) + (num_costs if include_prev_cost else 0)

    def forward(self, obs: torch.Tensor, *prev: torch.Tensor) -> torch.Tensor:
        parts = [obs if self.obs_norm is None else self.obs_norm(obs)]
        rest = list(prev)
        if self.include_prev_action:
            parts.append(((rest.pop(0) - self.center) / self.half_width).clamp(-1.0, 1.0))
        if self.include_prev_cost:
            parts.append(rest.pop(0))
        return parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)
