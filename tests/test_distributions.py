"""The actor's action distributions (policies/distributions.py) against hand-computed values."""

import re

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch import nn

from cmdp_rl import keys
from cmdp_rl.policies.distributions import (
    CategoricalHead,
    GaussianHead,
    action_outputs,
    make_action_head,
    sample,
)

LOG_2PI = 1.8378770664093453  # log(2 pi)


def gaussian_head() -> GaussianHead:
    """On the box [-2, 2] x [0, 4]: center (0, 2), half-width (2, 2); the network is the identity,
    and the log-stds log(1/2), log(1/4) make the scales 2 * (1/2, 1/4) = (1, 0.5)."""
    space = gym.spaces.Box(np.array([-2.0, 0.0], np.float32), np.array([2.0, 4.0], np.float32))
    head = make_action_head(space, nn.Identity(), init_log_std=-0.5)
    with torch.no_grad():
        head.log_std.copy_(torch.tensor([0.5, 0.25]).log())
    return head


def test_gaussian_on_a_box_has_the_hand_computed_parameters_log_prob_entropy_and_mode():
    head = gaussian_head()
    assert isinstance(head, GaussianHead) and head.log_std.shape == (2,)
    params = head(torch.tensor([[0.5, -0.25]]))
    # loc = center + half_width * net = (0 + 2 * 0.5, 2 + 2 * -0.25) = (1, 1.5)
    assert params[keys.LOC].tolist() == [[1.0, 1.5]]
    assert params[keys.SCALE].tolist() == [[1.0, 0.5]]
    dist = head.dist(params)
    # a = (1.5, 1): z = ((1.5 - 1) / 1, (1 - 1.5) / 0.5) = (0.5, -1);
    # log p = -(0.25 + 1) / 2 - (log 1 + log 0.5) - 2 * log(2 pi) / 2 = -0.625 + 0.693147 - 1.837877
    assert dist.log_prob(torch.tensor([[1.5, 1.0]])).item() == pytest.approx(-1.7697299, abs=1e-6)
    # entropy = sum over dims of (1 + log 2 pi) / 2 + log sigma = 1 + log 2 pi + log 0.5
    assert dist.entropy().item() == pytest.approx(2.1447299, abs=1e-6)
    assert dist.entropy().item() == pytest.approx(1 + LOG_2PI + np.log(0.5), abs=1e-6)
    assert sample(dist, deterministic=True).tolist() == [[1.0, 1.5]]  # the mode is the mean


def test_gaussian_samples_follow_loc_and_scale_and_carry_gradients():
    head = gaussian_head()
    dist = head.dist(head(torch.tensor([[0.5, -0.25]]).expand(20000, 2)))
    torch.manual_seed(0)
    a = sample(dist, deterministic=False)  # rsample: differentiable in the parameters
    assert a.shape == (20000, 2) and a.requires_grad
    assert a.mean(0).tolist() == pytest.approx([1.0, 1.5], abs=0.03)
    assert a.std(0).tolist() == pytest.approx([1.0, 0.5], abs=0.02)


LOGITS = torch.tensor(
    [
        [0.0, np.log(2.0), np.log(3.0)],  # probabilities (1, 2, 3) / 6
        [np.log(4.0), 0.0, 0.0],
    ],  # probabilities (4, 1, 1) / 6
    dtype=torch.float32,
)


def test_categorical_on_discrete_has_the_hand_computed_log_prob_entropy_and_mode():
    head = make_action_head(gym.spaces.Discrete(3), nn.Identity())
    assert isinstance(head, CategoricalHead)
    dist = head.dist(head(LOGITS))
    # Actions are [..., 1] indices. log p: row 0 action 2: log(3/6) = -0.693147; row 1 action 1: log(1/6)
    assert dist.log_prob(torch.tensor([[2], [1]])).tolist() == pytest.approx([-0.6931472, -1.7917595], abs=1e-6)
    assert dist.log_prob(torch.tensor([[0], [0]])).tolist() == pytest.approx([-1.7917595, -0.4054651], abs=1e-6)
    # entropy row 0: (1/6) log 6 + (2/6) log 3 + (3/6) log 2 = 0.298627 + 0.366204 + 0.346574
    # entropy row 1: (4/6) log 1.5 + 2 (1/6) log 6 = 0.270310 + 0.597253
    assert dist.entropy().tolist() == pytest.approx([1.0114043, 0.8675632], abs=1e-6)
    mode = sample(dist, deterministic=True)
    assert mode.tolist() == [[2], [0]] and mode.dtype == torch.int64


def test_categorical_samples_are_indices_with_the_given_frequencies():
    head = make_action_head(gym.spaces.Discrete(3), nn.Identity())
    dist = head.dist(head(LOGITS[:1].expand(30000, 3)))
    torch.manual_seed(0)
    a = sample(dist, deterministic=False)
    assert a.shape == (30000, 1) and a.dtype == torch.int64
    freq = torch.bincount(a.squeeze(-1), minlength=3) / 30000
    assert freq.tolist() == pytest.approx([1 / 6, 2 / 6, 3 / 6], abs=0.01)
    expected = torch.tensor([-1.7917595, -1.0986123, -0.6931472])[a.squeeze(-1)]  # log(1/6), log(2/6), log(3/6)
    assert torch.allclose(dist.log_prob(a), expected, atol=1e-6)


def test_the_action_space_chooses_the_network_outputs_and_refuses_others():
    assert action_outputs(gym.spaces.Box(-1, 1, (3,))) == 3  # one mean per dimension
    assert action_outputs(gym.spaces.Discrete(5)) == 5  # one logit per action
    assert action_outputs(gym.spaces.MultiDiscrete([2, 3])) == 5  # one logit per action of each component
    for bad in (gym.spaces.MultiBinary(2), gym.spaces.Text(4)):
        with pytest.raises(
            ValueError, match=re.escape(f"action space {bad} is not supported; supported: Box, Discrete")
        ):
            action_outputs(bad)
        with pytest.raises(ValueError, match="Box, Discrete"):
            make_action_head(bad, nn.Identity())
