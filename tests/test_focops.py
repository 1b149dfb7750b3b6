"""FOCOPS (Zhang, Vuong, Ross 2020): the projection loss's gradient at pi_k by hand, the per-state
KL indicator, nu's clipping to [0, multiplier.max], the KL early stop at delta, and a learning run."""

import csv

import pytest
import torch
from helpers.runs import tail_means
from torchrl.modules import IndependentNormal

from cmdp_rl import Collector, load_config, make_agent, make_algo, make_env, train
from cmdp_rl.algos.focops import focops_terms
from cmdp_rl.algos.multiplier import FINISHED, EpisodeCost
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.config.validation import ConfigError

A = torch.tensor([[0.4], [0.0], [-0.2]], dtype=torch.float64)  # actions, 3 states, 1-d
ADV = torch.tensor([[1.0], [-2.0], [0.5]], dtype=torch.float64)  # A_r - nu A_c
MU_K = torch.tensor([[0.1], [-0.2], [0.3]], dtype=torch.float64)  # pi_k's means
LOG_STD_K = torch.tensor([-0.7], dtype=torch.float64)


def _loss(mu, log_std, temperature=1.5, delta=0.02):
    old = IndependentNormal(MU_K, LOG_STD_K.exp().expand_as(MU_K))
    dist = IndependentNormal(mu, log_std.exp().expand_as(mu))
    terms, kl = focops_terms(dist, old, A, old.log_prob(A), ADV, temperature, delta)
    return terms.mean(), kl  # the loss the update minimises: the mean over states


def test_the_gradient_at_pi_k_is_the_policy_gradient_over_the_temperature():
    mu = MU_K.clone().requires_grad_()
    log_std = LOG_STD_K.clone().requires_grad_()
    loss, kl = _loss(mu, log_std, temperature=1.5)
    loss.backward()
    # At theta_k: KL = 0 and its gradient 0, every state inside; ratio = 1 with gradient grad log pi:
    # dL/dmu_j = -(1/lambda)(1/N) adv_j (a_j - mu_j) / sigma^2,
    # dL/dlog_sigma = -(1/lambda)(1/N) sum_j adv_j ((a_j - mu_j)^2 / sigma^2 - 1).
    var = (2 * LOG_STD_K).exp()
    z2 = (A - MU_K) ** 2 / var
    torch.testing.assert_close(kl, torch.zeros_like(kl))
    torch.testing.assert_close(mu.grad, -ADV * (A - MU_K) / var / (1.5 * 3))
    torch.testing.assert_close(log_std.grad, -(ADV * (z2 - 1)).sum(0) / (1.5 * 3))
    # e.g. state 0 by hand: sigma^2 = exp(-1.4) = 0.246597, -(1)(0.3)/0.246597/4.5 = -0.270347
    assert mu.grad[0, 0].item() == pytest.approx(-0.270347, abs=1e-6)


def test_a_state_past_delta_leaves_the_loss():
    # State 1's mean moved by 0.2 (KL = 0.2^2 / (2 sigma^2) = 0.0811 > 0.02), the others by 0.01.
    mu = (MU_K + torch.tensor([[0.01], [0.2], [0.01]], dtype=torch.float64)).requires_grad_()
    loss, kl = _loss(mu, LOG_STD_K.clone())
    loss.backward()
    assert kl[1].item() == pytest.approx(0.04 / (2 * (2 * LOG_STD_K).exp().item()))
    assert mu.grad[1].item() == 0.0 and mu.grad[0].item() != 0.0 and mu.grad[2].item() != 0.0
    # Away from pi_k the KL term pulls back: its gradient (mu - mu_k)/(N sigma^2) joins the state's.
    mu2 = mu.detach().clone().requires_grad_()
    _loss(mu2, LOG_STD_K.clone(), delta=1.0)[0].backward()
    var = (2 * LOG_STD_K).exp()
    dist_grad = (mu2 - MU_K).detach() / var / 3
    ratio = torch.exp(
        IndependentNormal(mu2.detach(), var.sqrt().expand_as(mu2)).log_prob(A)
        - IndependentNormal(MU_K, var.sqrt().expand_as(MU_K)).log_prob(A)
    ).unsqueeze(-1)
    torch.testing.assert_close(mu2.grad, dist_grad - ratio * ADV * (A - mu2.detach()) / var / (1.5 * 3))


def setup(algo: dict):
    cfg = load_config(
        {
            "algo": {"name": "focops", "update_epochs": 1, **algo},
            "rollout_steps": 32,
            "env": {"num_envs": 2, "max_steps": 3, "wall": "pass", "start": 0.45},
        }
    )
    torch.manual_seed(0)
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env)
    return make_algo(cfg.algo, agent), Collector(env, agent, cfg.rollout_steps, seed=0).collect()


def test_nu_is_projected_dual_ascent_clipped_to_0_and_its_max():
    algo, batch = setup({"cost_limit": 0.0, "multiplier": {"lr": 5.0, "max": 1.5, "init": 0.2}})
    stats = algo.update(batch)  # J_c of this batch is above 0.3 (most episodes cross): 0.2 + 5 * J_c > 1.5
    assert stats["lagrange_multiplier"] == 1.5
    algo.update_multiplier(EpisodeCost((0.1,), 3.0, FINISHED))  # still above d = 0: stays at the clamp
    assert algo.lagrange_multiplier == 1.5
    copy, _ = setup({"cost_limit": 0.0, "multiplier": {"lr": 5.0, "max": 1.5, "init": 0.2}})
    copy.load_state_dict(algo.state_dict())  # nu travels with the checkpoint
    assert copy.lagrange_multiplier == 1.5
    algo.update_multiplier(EpisodeCost((-1.0,), 3.0, FINISHED))  # a step of -5: clipped at 0
    assert algo.lagrange_multiplier == 0.0
    algo, _ = setup({"cost_limit": 1.0, "multiplier": {"lr": 0.1, "init": 0.5}})
    algo.update_multiplier(EpisodeCost((2.0,), 3.0, FINISHED))  # unclipped: 0.5 + 0.1 * (2 - 1)
    assert algo.lagrange_multiplier == pytest.approx(0.6)
    match = r"^algo.multiplier.init must be a number in \[0, algo.multiplier.max\], got 3.0$"
    with pytest.raises(ConfigError, match=match):  # the paper's clamp of 2 is focops' default
        load_config({"algo": {"name": "focops", "multiplier": {"init": 3.0}}})


def test_the_epochs_stop_at_the_first_minibatch_past_delta():
    algo, batch = setup({"target_kl": 1e-9, "num_minibatches": 4, "update_epochs": 3})
    calls = []
    terms = algo.policy_terms
    algo.policy_terms = lambda *args: calls.append(1) or terms(*args)
    algo.update(batch)
    assert len(calls) == 2  # the first minibatch is at pi_k (KL 0); after its step KL > delta: stop


@pytest.mark.slow  # a learning run (pyproject: markers)
def test_focops_learns_reach1d_within_budget(tmp_path):
    """Reach1D, passable wall, budget 0.5. The initial policy's training return is 0.00 (iteration 1,
    seed 0). With the paper's multiplier.lr = 0.01 and multiplier.max = 2, nu is too slow and too small here (cost 1.0
    per episode after 40 iterations): crossing is worth about 1.4 in reward. With multiplier.lr = 0.5 and
    multiplier.max = 3, measured on seed 0: last 10 iterations return 0.42 at cost 0.34."""
    cfg = compose_config(
        [
            "env=reach1d_torch",
            "env.wall=pass",
            "env.num_envs=256",
            "algo=focops",
            "algo.cost_limit=0.5",
            "algo.multiplier.lr=0.5",
            "algo.multiplier.max=3",
            "algo.num_minibatches=4",
            "algo.update_epochs=5",
            "total_steps=327680",
            "log_interval=1",
            "seed=0",
        ]
    )
    train(cfg, tmp_path, echo=lambda s: None)
    rows = list(csv.DictReader((tmp_path / "metrics.csv").open()))
    ret, cost = tail_means(tmp_path, "episode_return", "episode_cost")
    assert cost <= 0.5 + 0.2, cost
    assert ret >= 0.25 > float(rows[0]["episode_return"]) + 0.2, (ret, rows[0]["episode_return"])
    assert "outside_fraction" in rows[0]
