"""CPO's pieces: conjugate gradient, the Fisher-vector product, the dual of the trust-region
subproblem, and the line-searched step on hand-built batches."""

import math

import pytest
import torch
from helpers.policies import hand_built_units
from tensordict import TensorDict
from torch.distributions import kl_divergence

from cmdp_rl import Collector, keys, load_config, make_agent, make_algo, make_env
from cmdp_rl.algos.multiplier import FINISHED, RUNNING, WINDOW, EpisodeCost, EpisodeCostEstimate
from cmdp_rl.algos.trust_region.cpo import CONSTRAINED, RECOVERY, TRPO, fisher_vector_product, solve_dual
from cmdp_rl.algos.trust_region.natural_gradient import conjugate_gradient
from cmdp_rl.policies.agent import Actor
from cmdp_rl.policies.distributions import GaussianHead
from cmdp_rl.policies.mlp import MLPBody, mlp
from cmdp_rl.run.migrations import migrate


def test_conjugate_gradient_solves_a_random_spd_system():
    gen = torch.Generator().manual_seed(0)
    m = torch.randn(12, 12, generator=gen, dtype=torch.float64)
    a = m @ m.T + 0.5 * torch.eye(12, dtype=torch.float64)
    b = torch.randn(12, generator=gen, dtype=torch.float64)
    x = conjugate_gradient(lambda v: a @ v, b, iters=12)  # exact in n steps, up to rounding
    assert torch.allclose(x, torch.linalg.solve(a, b), rtol=1e-6, atol=1e-8)
    x3 = conjugate_gradient(lambda v: a @ v, b, iters=3)
    assert not torch.allclose(x3, torch.linalg.solve(a, b), rtol=1e-3)  # truncated: not yet there
    assert torch.equal(
        conjugate_gradient(lambda v: a @ v, torch.zeros(12, dtype=torch.float64), 5),
        torch.zeros(12, dtype=torch.float64),
    )


def _tiny_actor(hidden=(3,)):
    """The MLP policy's actor on a 2-D observation, actions in [-0.1, 0.1]."""
    cfg = load_config({"policy": {"hidden_sizes": list(hidden)}}).policy
    torch.manual_seed(0)
    net = mlp(2, cfg.hidden_sizes, 1, cfg.activation, out_gain=0.01)
    head = GaussianHead(net, torch.tensor([-0.1]), torch.tensor([0.1]), cfg.init_log_std)
    return Actor(MLPBody(None, None), head).double()


def test_fisher_vector_product_matches_the_analytic_fisher_of_the_gaussian_policy():
    actor = _tiny_actor()
    params = list(actor.parameters())
    n_params = sum(p.numel() for p in params)
    obs = {keys.OBS: torch.rand(7, 2, dtype=torch.float64)}
    with torch.no_grad():
        old = actor.params(obs)
    old_dist = actor.head.dist(old)
    kl = kl_divergence(old_dist, actor.dist(obs)).mean()
    fvp = fisher_vector_product(kl, params, damping=0.0)
    fvp_matrix = torch.stack([fvp(e) for e in torch.eye(n_params, dtype=torch.float64)], dim=1)

    # Analytic Fisher of N(mu, sigma) in (mu, log sigma): diag(1 / sigma^2, 2); chain rule through
    # the network's Jacobian, averaged over the states.
    fisher = torch.zeros(n_params, n_params, dtype=torch.float64)
    out = actor.params(obs)
    loc, log_scale = out[keys.LOC][:, 0], out[keys.SCALE][:, 0].log()
    for i in range(7):
        j_mu = torch.cat(
            [g.reshape(-1) for g in torch.autograd.grad(loc[i], params, retain_graph=True, materialize_grads=True)]
        )
        j_ls = torch.cat(
            [
                g.reshape(-1)
                for g in torch.autograd.grad(log_scale[i], params, retain_graph=True, materialize_grads=True)
            ]
        )
        sigma2 = out[keys.SCALE][i, 0].detach() ** 2
        fisher += (torch.outer(j_mu, j_mu) / sigma2 + 2.0 * torch.outer(j_ls, j_ls)) / 7
    assert fisher.abs().max() > 1.0  # a real matrix, not zeros
    assert torch.allclose(fvp_matrix, fisher, rtol=1e-8, atol=1e-8)
    v = torch.randn(n_params, dtype=torch.float64)
    assert torch.allclose(fisher_vector_product(kl, params, damping=0.3)(v), fisher @ v + 0.3 * v, atol=1e-8)


def _brute_force_max(g, b, H, c, delta, n=20_000):
    """max g.x over {1/2 x^T H x <= delta, c + b.x <= 0} in 2-D. A linear objective over this convex
    set peaks at an extreme point: on the ellipse's arc (tested densely) or at an end of the chord
    the line c + b.x = 0 cuts from it (computed exactly). None if the set is empty."""
    L = torch.linalg.cholesky(H)  # x = L^-T z maps the disk |z|^2 <= 2 delta onto the ellipse
    t = torch.linspace(0, 2 * math.pi, n, dtype=torch.float64)
    radius = math.sqrt(2 * delta)
    pts = torch.linalg.solve_triangular(L.T, radius * torch.stack([t.cos(), t.sin()]), upper=True).T
    # Chord ends: x = x0 + u w, w orthogonal to b, with 1/2 x^T H x = delta (a quadratic in u).
    x0 = -c * b / b.dot(b)
    w = torch.stack([-b[1], b[0]])
    qa, qb, qc = 0.5 * w @ H @ w, x0 @ H @ w, 0.5 * x0 @ H @ x0 - delta
    disc = qb * qb - 4 * qa * qc
    if disc >= 0:
        ends = torch.stack([x0 + u * w for u in ((-qb + disc.sqrt()) / (2 * qa), (-qb - disc.sqrt()) / (2 * qa))])
        pts = torch.cat([pts, ends])
    ok = (0.5 * ((pts @ H) * pts).sum(1) <= delta * (1 + 1e-9)) & (c + pts @ b <= 1e-12)
    return (pts[ok] @ g).max().item() if ok.any() else None


def test_dual_solution_is_the_optimum_of_the_trust_region_subproblem():
    gen = torch.Generator().manual_seed(1)
    delta = 0.01
    seen = set()
    for trial in range(60):
        m = torch.randn(2, 2, generator=gen, dtype=torch.float64)
        H = m @ m.T + 0.1 * torch.eye(2, dtype=torch.float64)
        g, b = torch.randn(2, generator=gen, dtype=torch.float64), torch.randn(2, generator=gen, dtype=torch.float64)
        h_inv_g, h_inv_b = torch.linalg.solve(H, g), torch.linalg.solve(H, b)
        q, r, s = g.dot(h_inv_g).item(), g.dot(h_inv_b).item(), b.dot(h_inv_b).item()
        edge = math.sqrt(2 * delta * s)  # |c| beyond this: whole region feasible (c < 0) or none is (c > 0)
        c = [-2.0 * edge, -0.5 * edge, 0.0, 0.5 * edge, 0.95 * edge, 1.5 * edge][trial % 6]
        sol = solve_dual(q, r, s, c, delta)
        seen.add(sol.case)
        if sol.case == CONSTRAINED:
            seen.add("active" if sol.nu > 0 else "inactive")
        if sol.case == RECOVERY:
            assert c > edge
            x = -sol.nu * h_inv_b
            # The recovery step is the trust region's cheapest point, on its boundary.
            assert 0.5 * x @ H @ x == pytest.approx(delta)
            assert c + b @ x == pytest.approx(c - edge)
            assert _brute_force_max(g, b, H, c, delta) is None  # nothing feasible indeed
            continue
        x = (h_inv_g - sol.nu * h_inv_b) / sol.lam
        assert 0.5 * x @ H @ x <= delta * (1 + 1e-6)
        assert c + b @ x <= 1e-9
        best = _brute_force_max(g, b, H, c, delta)
        assert g @ x == pytest.approx(best, rel=1e-4, abs=1e-7)
        if sol.case == TRPO:
            assert c < -edge and sol.nu == 0.0
    assert seen == {TRPO, CONSTRAINED, RECOVERY, "active", "inactive"}


def _surrogates(actor, units):
    with torch.no_grad():
        ratio = torch.exp(actor.dist({keys.OBS: units[keys.OBS]}).log_prob(units[keys.ACTION]) - units[keys.LOG_PROB])
        cost_adv = units[keys.COST_ADVANTAGE] - units[keys.COST_ADVANTAGE].mean()
        return (ratio[:, None] * units[keys.ADVANTAGE]).mean().item(), (ratio[:, None] * cost_adv).mean().item()


def _cpo(**algo):
    cfg = load_config({"algo": {"name": "cpo", "cost_limit": 1.0, **algo}, "policy": {"hidden_sizes": [16]}})
    torch.manual_seed(0)
    ac = make_agent(cfg.policy, make_env(cfg.env, num_envs=1))
    return make_algo(cfg.algo, ac)


@pytest.mark.parametrize("episode_cost,case", [(0.0, TRPO), (0.999, CONSTRAINED), (30.0, RECOVERY)])
def test_accepted_cpo_step_keeps_kl_within_delta_and_obeys_its_case(episode_cost, case):
    delta = 0.005
    cpo = _cpo(target_kl=delta, cg_damping=0.01, cg_iters=20)
    actor = cpo.agent.actor
    td = hand_built_units(actor)
    old_reward, old_cost = _surrogates(actor, td)
    old_dist = actor.head.dist({k: td[k] for k in (keys.LOC, keys.SCALE)})
    before = [p.detach().clone() for p in actor.parameters()]
    info = cpo.policy_step(td, episode_cost=episode_cost, episode_length=10.0)
    assert info["cpo_case"] == case
    assert info["step_fraction"] > 0.0  # a step was accepted ...
    assert any(not torch.equal(b, p) for b, p in zip(before, actor.parameters()))  # ... and taken
    with torch.no_grad():
        kl = kl_divergence(old_dist, actor.dist({keys.OBS: td[keys.OBS]})).mean().item()
    assert kl == pytest.approx(info["kl"], rel=1e-5) and 0.0 < kl <= delta
    new_reward, new_cost = _surrogates(actor, td)
    assert new_cost - old_cost == pytest.approx(info["surr_cost_change"], abs=1e-6)
    c = (episode_cost - 1.0) / 10.0
    if case == RECOVERY:
        assert new_cost < old_cost  # infeasible: the step lowers the cost surrogate
        assert info["dual_lambda"] == 0.0
    else:
        assert new_reward > old_reward
        assert new_cost - old_cost <= -c + 1e-9  # within the slack the budget leaves
    if case == TRPO:
        assert info["dual_nu"] == 0.0 and new_cost > old_cost  # the constraint did not hold it back
    if case == CONSTRAINED:
        assert info["dual_nu"] > 0.0  # the constraint is active


def test_cpo_update_on_collected_batch_changes_the_networks_and_checkpoints():
    cfg = load_config(
        {
            "algo": {"name": "cpo", "critic_epochs": 2, "critic_minibatches": 2},
            "env": {"num_envs": 2, "max_steps": 20},
            "rollout_steps": 32,
        }
    )
    torch.manual_seed(0)
    env = make_env(cfg.env)
    ac = make_agent(cfg.policy, env)
    cpo = make_algo(cfg.algo, ac)
    col = Collector(env, ac, cfg.rollout_steps, seed=0)
    before = [p.detach().clone() for p in ac.parameters()]
    stats = cpo.update(col.collect())
    assert all(not torch.equal(b, a) for b, a in zip(before, ac.parameters()))
    assert {
        "cpo_case",
        "step_fraction",
        "kl",
        "dual_lambda",
        "dual_nu",
        "lagrange_multiplier",
        "loss_v",
        "loss_vc",
    } <= stats.keys()
    assert stats["lagrange_multiplier"] == stats["dual_nu"] >= 0.0 and stats["kl"] <= cfg.algo.target_kl
    state = cpo.state_dict()
    cpo2 = make_algo(cfg.algo, make_agent(cfg.policy, env))
    cpo2.load_state_dict(state)
    assert cpo2.lagrange_multiplier == cpo.lagrange_multiplier
    assert all(torch.equal(a, b) for a, b in zip(cpo2.agent.parameters(), ac.parameters()))
    assert len(list(ac.parameters())) == len(list(cpo2.agent.parameters())) > 0


def _episode_batch(ends_at: list[int], cost_per_step: float = 1.0, T: int = 8) -> TensorDict:
    """[1, T] batch of running episode sums (an episode started before it), ending at ``ends_at``."""
    done = torch.zeros(1, T, 1, dtype=torch.bool)
    length = torch.arange(1, T + 1, dtype=torch.float32).reshape(1, T, 1) + 100  # 100 steps in already
    for t in ends_at:
        done[0, t] = True
    nxt = {
        keys.DONE: done,
        keys.EPISODE_LENGTH: length,
        keys.EPISODE_COST: length * cost_per_step,
        keys.EPISODE_RETURN: torch.zeros(1, T, 1),
    }
    return TensorDict({keys.NEXT: TensorDict(nxt, [1, T])}, [1, T])


def test_cpo_cost_estimate_carries_the_last_finished_episodes_over_batches_where_none_ended():
    """A long episode spans several batches: its cost so far is a lower bound, not J_c. CPO reads
    the shared estimate (algos/multiplier.py): the episodes that ended in the batch, else the last
    ones that ended (a window of one per env), else the running sums."""
    assert EpisodeCostEstimate().update(_episode_batch([3]))[:3] == EpisodeCost((104.0,), 104.0, FINISHED)[:3]
    assert EpisodeCostEstimate().update(_episode_batch([]))[:3] == EpisodeCost((108.0,), 108.0, RUNNING)[:3]
    cpo = _cpo()
    cpo.policy_step = lambda units, cost, length, estimate=None: {"seen": (cost, length)}  # only what update passes on
    cpo.fit_critics = lambda *args: {}
    cpo.gae = lambda batch, agent: batch
    seen = []
    for ends in ([], [5], [], []):
        batch = _episode_batch(ends, cost_per_step=0.5)
        seen.append(cpo.update(batch)["seen"])
    assert seen == [(54.0, 108.0), (53.0, 106.0), (53.0, 106.0), (53.0, 106.0)]
    assert cpo.state_dict()["episode_cost"] == {"recent": [(53.0, 106.0)], "window": 1, "episodes": [(53.0,)]}
    fresh = _cpo()
    fresh.load_state_dict(cpo.state_dict())
    assert fresh.episode_cost.update(_episode_batch([]))[:3] == EpisodeCost((53.0,), 106.0, WINDOW)[:3]
    # A checkpoint from before the shared estimate kept CPO's last J_c as "episode_estimate" (format 2:
    # cmdp_rl.run.migrations brings it to the current layout).
    old = {k: v for k, v in cpo.state_dict().items() if k != "episode_cost"}
    old["episode_estimate"] = (51.0, 102.0)
    fresh = _cpo()
    fresh.load_state_dict(migrate({"format": 2, "algo": "cpo", "algo_state": old})["members"][0]["algo_state"])
    assert fresh.episode_cost.update(_episode_batch([]))[:3] == EpisodeCost((51.0,), 102.0, WINDOW)[:3]
