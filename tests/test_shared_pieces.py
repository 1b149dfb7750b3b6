"""The pieces every algorithm shares: the J_c estimate and the minibatch iterator, against
hand-computed values."""

import pytest
import torch
from tensordict import TensorDict

from cmdp_rl import keys
from cmdp_rl.algos.minibatch import minibatches
from cmdp_rl.algos.multiplier import FINISHED, RUNNING, WINDOW, EpisodeCostEstimate


def batch(done, cost, length):
    """A [N, T] batch whose ("next", ...) entries are the given per-step lists of lists."""
    t = lambda x, dt: torch.tensor(x, dtype=dt).unsqueeze(-1)  # noqa: E731
    n, T = len(done), len(done[0])
    nxt = {
        keys.DONE: t(done, torch.bool),
        keys.EPISODE_COST: t(cost, torch.float32),
        keys.EPISODE_LENGTH: t(length, torch.int64),
        keys.EPISODE_RETURN: t(cost, torch.float32),
    }
    return TensorDict({keys.NEXT: TensorDict(nxt, batch_size=[n, T])}, batch_size=[n, T])


def test_j_c_from_this_batch_then_the_window_then_running_cost():
    est = EpisodeCostEstimate(window=2)
    # Nothing has ended yet: the running episodes' cost so far (a lower bound), at the last step.
    first = est.update(batch([[0, 0], [0, 0]], [[0, 1], [2, 2]], [[1, 2], [1, 2]]))
    assert first[:3] == (pytest.approx((1.5,)), pytest.approx(2.0), RUNNING)
    assert (first.window_costs, first.fresh) == (None, 0)  # no episode has ended: the per-episode window is empty
    # Three episodes end here (costs 4, 1, 3; lengths 10, 20, 30): their mean.
    got = est.update(batch([[1, 0, 1], [0, 1, 0]], [[4, 0, 1], [0, 3, 0]], [[10, 1, 20], [1, 30, 1]]))
    assert got[:3] == (pytest.approx((8 / 3,)), pytest.approx(20.0), FINISHED)
    assert (got.window_costs, got.fresh) == (pytest.approx((8 / 3,)), 3)
    # None ends: the last window=2 episodes to end, in order of the batch's rows (1 and 3).
    later = est.update(batch([[0], [0]], [[7], [7]], [[5], [5]]))
    assert later[:3] == (pytest.approx((2.0,)), pytest.approx(25.0), WINDOW)
    assert (later.window_costs, later.fresh) == (pytest.approx((8 / 3,)), 0)  # all three ended episodes, none new
    # The window survives a checkpoint.
    again = EpisodeCostEstimate(window=2)
    again.load_state_dict(est.state_dict())
    restored = again.update(batch([[0], [0]], [[0], [0]], [[1], [1]]))
    assert restored.window_costs == pytest.approx((8 / 3,))  # the per-episode window too
    assert restored[:3] == (
        pytest.approx((2.0,)),
        pytest.approx(25.0),
        WINDOW,
    )


def test_minibatches_cover_every_unit_once_per_epoch_and_repeat_with_the_seed():
    data = {"x": torch.arange(12), "y": torch.arange(12) * 10}
    torch.manual_seed(0)
    out = list(minibatches(data, num_minibatches=3, epochs=2))
    assert [e for e, _ in out] == [0, 0, 0, 1, 1, 1]
    for epoch in (0, 1):
        xs = torch.cat([mb["x"] for e, mb in out if e == epoch])
        assert sorted(xs.tolist()) == list(range(12))
    assert all(torch.equal(mb["y"], mb["x"] * 10) for _, mb in out)  # rows stay aligned
    torch.manual_seed(0)
    assert all(torch.equal(a["x"], b["x"]) for (_, a), (_, b) in zip(out, minibatches(data, 3, 2)))
    # 10 units in 3 minibatches: slices of 3, one unit left out of each pass.
    assert [mb["x"].numel() for _, mb in minibatches({"x": torch.arange(10)}, 3)] == [3, 3, 3]
    with pytest.raises(ValueError, match="at most 2"):
        list(minibatches({"x": torch.arange(2)}, 3))
