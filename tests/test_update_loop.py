"""The PPO family's update loop (algos/ppo.py: ppo_update, SingleLearner; algos/minibatch.py): a run's
minibatch order is ``minibatches()``'s under the same seed, a KL stop ends the update after
evaluating its minibatch and draws no further order, the statistics average the minibatches each
member evaluated, and a run's optimiser step is torch's, bit for bit."""

import pytest
import torch
from torch import nn

from cmdp_rl import Collector, load_config, make_agent, make_algo, make_env
from cmdp_rl.algos.learner import SingleLearner, clip_grad_norm_
from cmdp_rl.algos.minibatch import Tally, minibatches


def _data() -> dict:
    return {"x": torch.arange(10.0).unsqueeze(1), "y": torch.arange(10.0, 20.0)}


def test_a_run_visits_the_minibatches_of_minibatches():
    torch.manual_seed(0)
    expected = [{k: v.clone() for k, v in mb.items()} for _, mb in minibatches(_data(), 3, 2)]
    torch.manual_seed(0)
    run = SingleLearner(None, 1.0)
    seen = [{k: v.clone() for k, v in mb.items()} for _ in range(2) for mb in run.minibatches(_data(), 3)]
    assert len(seen) == len(expected) == 6
    for a, b in zip(seen, expected):
        assert all(torch.equal(a[k], b[k]) for k in b)


def test_a_kl_stop_ends_the_update_after_evaluating_its_minibatch():
    """The first minibatch is at the behaviour policy (KL 0) and steps; the second is past the
    limit: evaluated, not stepped, and no later order is drawn (the run's random stream is the one
    of a single permutation)."""
    cfg = load_config(
        {
            "algo": {"name": "ppo", "update_epochs": 3, "num_minibatches": 4, "target_kl": 1e-12, "lr": 1e-2},
            "env": {"num_envs": 2, "max_steps": 20},
            "rollout_steps": 32,
        }
    )
    torch.manual_seed(0)
    env = make_env(cfg.env)
    algo = make_algo(cfg.algo, make_agent(cfg.policy, env))
    batch = Collector(env, algo.agent, cfg.rollout_steps, seed=0).collect()
    calls = []
    terms = algo.policy_terms
    algo.policy_terms = lambda *args: calls.append(1) or terms(*args)
    saved = torch.get_rng_state()
    algo.update(batch)
    after = torch.rand(1)
    torch.set_rng_state(saved)
    torch.randperm(2 * 32)  # the one permutation the update drew
    assert len(calls) == 2 and torch.equal(after, torch.rand(1))
    assert {int(algo.actor_opt.state[p]["step"]) for p in algo.actor_params} == {1}


def test_the_means_are_over_the_minibatches_each_member_evaluated():
    run = Tally()
    run.add({"kl": torch.tensor(1.0)})
    run.add({"kl": torch.tensor(3.0)})
    assert run.means()["kl"].item() == 2.0
    population = Tally()  # three members; the second stops after the first minibatch
    population.add({"kl": torch.tensor([1.0, 2.0, 3.0])}, torch.tensor([True, True, True]))
    population.add({"kl": torch.tensor([5.0, 9.0, 7.0])}, torch.tensor([True, False, True]))
    assert population.means()["kl"].tolist() == [3.0, 2.0, 5.0]


def _twin_nets(seed: int = 0) -> tuple:

    from cmdp_rl.policies.mlp import mlp

    torch.manual_seed(seed)
    a = mlp(3, [16, 16], 2, "tanh")
    b = mlp(3, [16, 16], 2, "tanh")
    b.load_state_dict(a.state_dict())

    return a, b


@pytest.mark.cpu_kernels
def test_a_runs_optimiser_step_is_torchs_bit_for_bit():
    """SingleLearner.step (one backward, the foreach clipping, torch's functional fused Adam on the
    optimiser's state) against torch's own calls (``clip_grad_norm_``, ``Adam.step``), over steps
    that clip and an annealed learning rate."""
    a, b = _twin_nets()
    opt_a = torch.optim.Adam(a.parameters(), lr=1e-2, fused=True)
    opt_b = torch.optim.Adam(b.parameters(), lr=1e-2, fused=True)
    run = SingleLearner(None, max_grad_norm=0.5)
    gen = torch.Generator().manual_seed(1)
    for i in range(6):
        x = 10 * torch.randn(32, 3, generator=gen)  # large inputs: gradients over the clip
        for opt in (opt_a, opt_b):
            opt.param_groups[0]["lr"] = 1e-2 * (1 - i / 6)
        opt_a.zero_grad()
        a(x).pow(2).sum().backward()
        assert nn.utils.clip_grad_norm_(list(a.parameters()), 0.5) > 0.5
        opt_a.step()
        run.step(b(x).pow(2).sum(), [(opt_b, list(b.parameters()))])
        assert all(torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters()))
    assert opt_b.state[next(b.parameters())]["step"].item() == 6


@pytest.mark.cpu_kernels
def test_the_clipping_is_torchs():
    a, b = _twin_nets()
    x = 10 * torch.randn(8, 3)
    for net in (a, b):
        net(x).pow(2).sum().backward()
    nn.utils.clip_grad_norm_(list(a.parameters()), 0.1)
    clip_grad_norm_(list(b.parameters()), 0.1)
    assert all(torch.equal(p.grad, q.grad) for p, q in zip(a.parameters(), b.parameters()))


def test_the_mlp_computes_what_nn_sequential_computes():
    a, _ = _twin_nets()
    x = torch.randn(5, 3)
    assert torch.equal(a(x), nn.Sequential.forward(a, x))


def test_after_its_first_step_a_fused_adam_steps_through_the_functional_api(monkeypatch):
    """The first step creates Adam's moments (``Adam.step``); later ones skip ``Optimizer.step``'s
    wrappers (the reason for ``adam_step``): a silent fallback would cost the run its speed."""
    from cmdp_rl.algos.learner import adam_step

    net, _ = _twin_nets()
    opt = torch.optim.Adam(net.parameters(), lr=1e-2, fused=True)
    net(torch.randn(4, 3)).sum().backward()
    adam_step(opt)
    monkeypatch.setattr(torch.optim.Adam, "step", lambda *a, **k: pytest.fail("Optimizer.step called"))
    adam_step(opt)
    assert opt.state[next(net.parameters())]["step"].item() == 2
