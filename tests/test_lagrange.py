import pytest

from cmdp_rl.algos import DualAscent


def test_lambda_rises_above_budget_falls_below_and_stays_nonnegative():
    m = DualAscent(cost_limit=2.0, lr=0.5)
    assert m.update(6.0) == pytest.approx(2.0)   # J_c > d: up by lr * (J_c - d)
    assert m.update(4.0) == pytest.approx(3.0)
    assert m.update(1.0) == pytest.approx(2.5)   # J_c < d: down
    assert m.update(0.0) == pytest.approx(1.5)
    assert m.update(0.0) == pytest.approx(0.5)
    assert m.update(0.0) == 0.0                  # projected: never below 0
    assert m.update(0.0) == 0.0


def test_state_round_trip_and_bad_input():
    m = DualAscent(1.0, 0.1, init=0.7)
    m2 = DualAscent(1.0, 0.1)
    m2.load_state_dict(m.state_dict())
    assert m2.value == 0.7
    with pytest.raises(ValueError, match="episode_cost"):
        m.update(float("nan"))
    with pytest.raises(ValueError, match="lambda_init"):
        DualAscent(1.0, 0.1, init=-1.0)
