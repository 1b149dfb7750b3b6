"""The minibatch loop a run and a population share (algos/update_backend.py): with one agent it
visits the minibatches ``minibatches()`` gives under the same seed, and a KL stop ends it after
evaluating that minibatch, drawing no further permutation (the run's numbers do not move)."""

import torch

from cmdp_rl.algos.minibatch import minibatches
from cmdp_rl.algos.update_backend import OneAgent, run_epochs


def _data() -> dict:
    return {"x": torch.arange(10.0).unsqueeze(1), "y": torch.arange(10.0, 20.0)}


def test_one_agent_visits_the_minibatches_of_minibatches():
    torch.manual_seed(0)
    expected = [{k: v.clone() for k, v in mb.items()} for _, mb in minibatches(_data(), 3, 2)]
    torch.manual_seed(0)
    seen = []

    def step(mb, active):
        seen.append({k: v.clone() for k, v in mb.items()})
        return {"n": torch.tensor(1.0), "x": mb["x"].sum()}, active

    sums, count = run_epochs(OneAgent(None, 1.0, None), _data(), 3, 2, step)
    assert len(seen) == len(expected) == 6 and count == 6 and sums["n"].item() == 6
    for a, b in zip(seen, expected):
        assert all(torch.equal(a[k], b[k]) for k in b)
    assert sums["x"].item() == sum(mb["x"].sum().item() for mb in expected)


def test_a_kl_stop_ends_the_loop_after_evaluating_its_minibatch():
    backend = OneAgent(None, 1.0, kl_limit=0.5)
    calls = []

    def step(mb, active):
        calls.append(1)
        kl = torch.tensor(0.0 if len(calls) < 2 else 1.0)  # the second minibatch is past the limit
        active, stepping = backend.stop(kl, active)
        assert stepping == (len(calls) < 2)
        return {"kl": kl}, active

    torch.manual_seed(0)
    sums, count = run_epochs(backend, _data(), 3, 4, step)
    after = torch.rand(1)
    torch.manual_seed(0)
    torch.randperm(10)  # the one permutation the loop drew
    assert len(calls) == count == 2 and sums["kl"].item() == 1.0
    assert torch.equal(after, torch.rand(1))


def _twin_nets(seed: int = 0) -> tuple:

    from cmdp_rl.policies.mlp import mlp

    torch.manual_seed(seed)
    a = mlp(3, [16, 16], 2, "tanh")
    b = mlp(3, [16, 16], 2, "tanh")
    b.load_state_dict(a.state_dict())

    return a, b


def test_adam_step_and_clipping_are_torchs_bit_for_bit():
    """The one-agent backend's Adam step and gradient clipping against torch's own, over steps
    that clip and an annealed learning rate."""
    from torch import nn

    from cmdp_rl.algos.update_backend import adam_step, clip_grad_norm_

    a, b = _twin_nets()
    opt_a = torch.optim.Adam(a.parameters(), lr=1e-2, fused=True)
    opt_b = torch.optim.Adam(b.parameters(), lr=1e-2, fused=True)
    gen = torch.Generator().manual_seed(1)
    for i in range(6):
        x = 10 * torch.randn(32, 3, generator=gen)  # large inputs: gradients over the clip
        for net, opt in ((a, opt_a), (b, opt_b)):
            opt.param_groups[0]["lr"] = 1e-2 * (1 - i / 6)
            for p in net.parameters():
                p.grad = None
            net(x).pow(2).sum().backward()
        norm = nn.utils.clip_grad_norm_(list(a.parameters()), 0.5)
        assert norm > 0.5
        clip_grad_norm_(list(b.parameters()), 0.5)
        assert all(torch.equal(p.grad, q.grad) for p, q in zip(a.parameters(), b.parameters()))
        opt_a.step()
        adam_step(opt_b)
        assert all(torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters()))
    assert opt_b.state[next(b.parameters())]["step"].item() == 6


def test_the_mlp_computes_what_nn_sequential_computes():
    from torch import nn

    a, _ = _twin_nets()
    x = torch.randn(5, 3)
    assert torch.equal(a(x), nn.Sequential.forward(a, x))
