import pytest

from cmdp_rl.algos.multiplier import DualAscent


def test_lambda_rises_above_budget_falls_below_and_stays_nonnegative():
    m = DualAscent(cost_limit=2.0, lr=0.5)
    assert m.update(6.0) == pytest.approx(2.0)  # J_c > d: up by lr * (J_c - d)
    assert m.update(4.0) == pytest.approx(3.0)
    assert m.update(1.0) == pytest.approx(2.5)  # J_c < d: down
    assert m.update(0.0) == pytest.approx(1.5)
    assert m.update(0.0) == pytest.approx(0.5)
    assert m.update(0.0) == 0.0  # projected: never below 0
    assert m.update(0.0) == 0.0


def test_state_round_trip_and_bad_input():
    m = DualAscent(1.0, 0.1, init=0.7)
    m2 = DualAscent(1.0, 0.1)
    m2.load_state_dict(m.state_dict())
    assert m2.value == 0.7
    with pytest.raises(ValueError, match="episode_cost"):
        m.update(float("nan"))
    with pytest.raises(ValueError, match="algo.multiplier.init"):
        DualAscent(1.0, 0.1, init=-1.0)


# --- PID Lagrangian (Stooke, Achiam, Abbeel 2020) ---------------------------------------------
import random

from cmdp_rl.algos.multiplier import MultiplierController, PIDLagrangian

COSTS = [6.0, 4.0, 1.0, 0.0, 0.0, 0.0, 0.0, 3.5, 2.0, 2.0, 0.5, 9.0, 0.0]


def test_both_controllers_share_one_interface():
    for m in (DualAscent(1.0, 0.1), PIDLagrangian(1.0, kp=0.1, ki=0.1, kd=0.1)):
        assert isinstance(m, MultiplierController)
        assert m.update(2.0) == m.value and isinstance(m.state_dict(), dict)


@pytest.mark.parametrize("init", [0.0, 0.7])
def test_integral_only_pid_is_dual_ascent_exactly(init):
    rng = random.Random(0)
    costs = COSTS + [rng.uniform(0.0, 5.0) for _ in range(50)]
    dual = DualAscent(cost_limit=2.0, lr=0.3, init=init)
    pid = PIDLagrangian(cost_limit=2.0, kp=0.0, ki=0.3, kd=0.0, init=init, p_ema_alpha=0.5, d_ema_alpha=0.5)
    seq_dual = [dual.update(c) for c in costs]
    seq_pid = [pid.update(c) for c in costs]
    assert seq_pid == seq_dual  # bit for bit, not approximately
    assert 0.0 in seq_dual and max(seq_dual) > 0.0  # the sequence exercised the projection at 0


def test_pid_lambda_never_negative_and_integral_does_not_wind_below_zero():
    pid = PIDLagrangian(cost_limit=2.0, kp=1.0, ki=0.5, kd=1.0)
    for c in [0.0] * 20:  # long feasible stretch: P term is -2, integral would go to -20 unclamped
        assert pid.update(c) == 0.0
        assert pid.integral == 0.0
    # One step over budget lifts lambda at once; an unclamped integral would still be deep below 0.
    assert pid.update(3.0) == pytest.approx(1.0 * 1.0 + 0.5 * 1.0 + 1.0 * 3.0)


def test_proportional_term_reacts_in_the_same_iteration():
    pi = PIDLagrangian(cost_limit=1.0, kp=0.0, ki=0.1, kd=0.0)
    ppi = PIDLagrangian(cost_limit=1.0, kp=2.0, ki=0.1, kd=0.0)
    assert pi.update(4.0) == pytest.approx(0.3)
    assert ppi.update(4.0) == pytest.approx(0.3 + 2.0 * 3.0)  # Kp * (J_c - d) on the first violation
    # ... and lets go as soon as the cost is back under budget, while the integral remembers.
    assert ppi.update(1.0) == pytest.approx(0.3)
    assert ppi.update(0.0) == 0.0  # 0.2 + 2 * (0 - 1) < 0: projected to 0 ...
    assert ppi.integral == pytest.approx(0.2)  # ... while the integral keeps its 0.2


def test_derivative_acts_on_rising_smoothed_cost_only():
    pid = PIDLagrangian(cost_limit=10.0, kp=0.0, ki=0.0, kd=1.0, d_ema_alpha=0.5)
    assert pid.update(0.0) == 0.0  # first measurement: no derivative yet
    assert pid.update(4.0) == pytest.approx(2.0)  # EMA 0 -> 2: D = 2
    assert pid.update(4.0) == pytest.approx(1.0)  # EMA 2 -> 3
    assert pid.update(0.0) == 0.0  # EMA 3 -> 1.5: falling cost, positive part is 0


def test_lambda_max_clamps_lambda_and_integral():
    pid = PIDLagrangian(cost_limit=0.0, kp=1.0, ki=1.0, kd=0.0, lambda_max=2.5)
    for _ in range(5):
        assert pid.update(2.0) <= 2.5
    assert pid.integral == 2.5 and pid.value == 2.5
    assert pid.update(0.0) == pytest.approx(2.5)  # no wound-up excess to unwind


def test_pid_state_round_trip_continues_identically():
    kw = dict(cost_limit=1.5, kp=0.4, ki=0.2, kd=0.3, p_ema_alpha=0.3, d_ema_alpha=0.6, d_delay=3)
    a = PIDLagrangian(**kw)
    for c in COSTS[:6]:
        a.update(c)
    b = PIDLagrangian(**kw)
    b.load_state_dict(a.state_dict())
    assert b.value == a.value
    assert [a.update(c) for c in COSTS[6:]] == [b.update(c) for c in COSTS[6:]]


def test_pid_bad_arguments():
    with pytest.raises(ValueError, match="gains"):
        PIDLagrangian(1.0, kp=-1.0, ki=0.1, kd=0.0)
    with pytest.raises(ValueError, match="episode_cost"):
        PIDLagrangian(1.0, kp=1.0, ki=0.1, kd=0.0).update(float("inf"))
