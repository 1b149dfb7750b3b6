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
