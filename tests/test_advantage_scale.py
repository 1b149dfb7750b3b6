"""``advantage_scale``: what the Lagrangian's multiplier weighs (algos/ppo_lag.py: lagrangian_advantage).

Checked against hand-computed advantages, and for the property it exists for: with
``advantage_scale: standardized`` and the budget-relative dual step, costs (and budgets) in other
units give the same multiplier and the same policy advantage.
"""

from __future__ import annotations

import math

import pytest
import torch
from helpers.cost_envs import two_cost_cfg, two_cost_env
from tensordict import TensorDict

from cmdp_rl import keys, load_config
from cmdp_rl.algos import make_algo
from cmdp_rl.algos.multiplier import FINISHED, EpisodeCost
from cmdp_rl.algos.ppo_lag import lagrangian_advantage
from cmdp_rl.policies import make_agent
from cmdp_rl.policies.mlp import PolicyConfig


def _batch(adv: list[float], cost_adv: list[list[float]]) -> TensorDict:
    return TensorDict(
        {
            keys.ADVANTAGE: torch.tensor(adv, dtype=torch.float64).view(1, -1, 1),
            keys.COST_ADVANTAGE: torch.tensor(cost_adv, dtype=torch.float64).view(1, len(adv), -1),
        },
        batch_size=[1, len(adv)],
    )


def test_raw_is_the_classical_lagrangian_advantage():
    batch = _batch([1.0, 3.0], [[0.0], [4.0]])
    # (A_r - 0.5 A_c) / 1.5
    expected = torch.tensor([1.0 / 1.5, (3.0 - 2.0) / 1.5], dtype=torch.float64).view(1, 2, 1)
    assert torch.allclose(lagrangian_advantage(batch, [0.5], "raw"), expected)


def test_standardized_weighs_each_signal_at_unit_spread():
    batch = _batch([1.0, 3.0, 5.0], [[0.0, 10.0], [0.0, 20.0], [30.0, 60.0]])
    # A_r: mean 3, sample std 2 -> [-1, 0, 1]. A_c,0: mean 10, std sqrt(300) -> [-1, -1, 2] / sqrt(3).
    # A_c,1: mean 30, std sqrt(700) -> [-20, -10, 30] / sqrt(700).
    a = torch.tensor([-1.0, 0.0, 1.0])
    c0 = torch.tensor([-1.0, -1.0, 2.0]) / math.sqrt(3.0)
    c1 = torch.tensor([-20.0, -10.0, 30.0]) / math.sqrt(700.0)
    expected = ((a - 0.5 * c0 - 2.0 * c1) / 3.5).to(torch.float64).view(1, 3, 1)
    assert torch.allclose(lagrangian_advantage(batch, [0.5, 2.0], "standardized"), expected, atol=1e-7)
    # A cost never paid in the batch has no spread: it weighs nothing, and nothing is divided by 0.
    flat = _batch([1.0, 3.0], [[0.0], [0.0]])
    assert torch.allclose(
        lagrangian_advantage(flat, [1.0], "standardized"),
        torch.tensor([-1.0, 1.0], dtype=torch.float64).view(1, 2, 1) / math.sqrt(2.0) / 2.0,
    )


@pytest.mark.parametrize("algo", ["ppo_lag", "pid_lag"])
def test_standardized_with_the_budget_step_is_unit_free(algo):
    """The same update in cost units 1 and 100: costs, cost advantages and budgets all x100."""
    env = two_cost_env()
    gen = torch.Generator().manual_seed(0)
    adv = torch.randn(1, 6, 1, generator=gen, dtype=torch.float64)
    cost_adv = torch.randn(1, 6, 2, generator=gen, dtype=torch.float64)
    results = []
    for unit in (1.0, 100.0):
        cfg = load_config(
            two_cost_cfg(algo={"name": algo, "advantage_scale": "standardized", "cost_limit": [0.5 * unit, 1.0 * unit]})
        ).algo
        lag = make_algo(cfg, make_agent(PolicyConfig(), env))
        for j_c in ((0.9, 0.2), (1.4, 1.6), (0.7, 1.1)):
            lag.update_multiplier(EpisodeCost(tuple(unit * j for j in j_c), 4.0, FINISHED))
        batch = TensorDict({keys.ADVANTAGE: adv, keys.COST_ADVANTAGE: unit * cost_adv}, batch_size=[1, 6])
        results.append((list(lag.multiplier.values), lag.policy_advantage(batch)))
    (lam1, adv1), (lam100, adv100) = results
    assert lam1 == pytest.approx(lam100, rel=1e-12) and min(lam1) > 0
    assert torch.allclose(adv1, adv100, rtol=1e-6, atol=1e-9)  # up to the 1e-8 guard on the std
    # In raw units the same multipliers would hand the update to the cost measured in hundreds.
    raw = lagrangian_advantage(TensorDict({keys.ADVANTAGE: adv, keys.COST_ADVANTAGE: 100 * cost_adv}, [1, 6]), lam1)
    assert not torch.allclose(raw, adv1, atol=1e-3)
