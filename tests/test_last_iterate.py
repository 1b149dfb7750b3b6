"""The multiplier updates of algos/multiplier.py and the budget-normalised violation, each against
a sequence worked out by hand (the arithmetic is in the comments)."""

import math

import pytest

from cmdp_rl.algos.multiplier import (
    EPISODE_WINDOW,
    FINISHED,
    RUNNING,
    WINDOW,
    AugmentedLagrangian,
    DualAscent,
    EpisodeCost,
    LogDual,
    Multipliers,
    OptimisticDual,
    PIDLagrangian,
    RegularizedDual,
)
from cmdp_rl.algos.multiplier_options import multiplier_options


def test_budget_scale_makes_dual_ascent_unit_free():
    # d = 2, scale 2: g = (J_c - 2) / 2. J_c = 6 -> g = 2, lambda 0 + 0.5 * 2 = 1.0;
    # J_c = 1 -> g = -0.5, lambda 1.0 - 0.25 = 0.75; J_c = 0 -> g = -1, lambda 0.25; again -> 0.
    m = DualAscent(cost_limit=2.0, lr=0.5, scale=2.0)
    assert [m.update(c) for c in (6.0, 1.0, 0.0, 0.0)] == pytest.approx([1.0, 0.75, 0.25, 0.0])
    # The same relative violations in units 100 times larger give the same lambdas.
    big = DualAscent(cost_limit=200.0, lr=0.5, scale=200.0)
    assert [big.update(c) for c in (600.0, 100.0, 0.0, 0.0)] == pytest.approx([1.0, 0.75, 0.25, 0.0])


def test_budget_scale_in_pid():
    # d = 4, scale 4, kp = 1, ki = 0.5: J_c = 8 -> g = 1, I = 0.5, lambda = 1 + 0.5 = 1.5;
    # J_c = 2 -> g = -0.5, I = 0.25, lambda = -0.5 + 0.25 < 0 -> 0.
    pid = PIDLagrangian(4.0, kp=1.0, ki=0.5, kd=0.0, scale=4.0)
    assert pid.update(8.0) == pytest.approx(1.5)
    assert pid.update(2.0) == 0.0 and pid.integral == pytest.approx(0.25)


def test_regularized_dual_ding_et_al():
    # lr = 0.5, tau = 0.4: lambda <- max(0, 0.8 lambda + 0.5 g), d = 1.
    # J_c = 3 (g 2): 0.8*0 + 1 = 1.0; J_c = 3: 0.8 + 1 = 1.8; J_c = 1 (g 0): 1.44;
    # J_c = 0 (g -1): 1.152 - 0.5 = 0.652; J_c = 0: 0.5216 - 0.5 = 0.0216; J_c = 0: < 0 -> 0.
    m = RegularizedDual(cost_limit=1.0, lr=0.5, tau=0.4)
    seq = [m.update(c) for c in (3.0, 3.0, 1.0, 0.0, 0.0, 0.0)]
    assert seq == pytest.approx([1.0, 1.8, 1.44, 0.652, 0.0216, 0.0])
    # At a fixed point the violation is tau * lambda: g = 0.4 * lambda holds lambda still.
    fixed = RegularizedDual(cost_limit=1.0, lr=0.5, tau=0.4, init=2.0)
    assert fixed.update(1.0 + 0.4 * 2.0) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="algo.multiplier.tau"):
        RegularizedDual(1.0, lr=0.5, tau=2.0)


def test_optimistic_dual_is_the_optimistic_gradient_with_nu_zero():
    # lr = 0.5, d = 1, nu = 0: lambda <- max(0, lambda + 0.5 (2 g_t - g_{t-1})), first step plain.
    # g: 2, 1, 0, -1, -1.  1.0; 1.0 + 0.5 (2 - 2) = 1.0; 1.0 + 0.5 (0 - 1) = 0.5;
    # 0.5 + 0.5 (-2 - 0) = -0.5 -> 0; 0 + 0.5 (-2 + 1) < 0 -> 0.
    m = OptimisticDual(cost_limit=1.0, lr=0.5)
    assert [m.update(c) for c in (3.0, 2.0, 1.0, 0.0, 0.0)] == pytest.approx([1.0, 1.0, 0.5, 0.0, 0.0])


def test_optimistic_dual_nupi_ema():
    # lr = 1, nu = 0.5, d = 0. g: 2, 4, 0.  xi: 2 (first: xi_prev = xi = 2), 0.5*2 + 0.5*4 = 3,
    # 0.5*3 + 0 = 1.5. lambda: 0 + 2 + 0 = 2; 2 + 4 + (3 - 2) = 7; 7 + 0 + (1.5 - 3) = 5.5.
    m = OptimisticDual(cost_limit=0.0, lr=1.0, nu=0.5)
    assert [m.update(c) for c in (2.0, 4.0, 0.0)] == pytest.approx([2.0, 7.0, 5.5])
    again = OptimisticDual(cost_limit=0.0, lr=1.0, nu=0.5)
    again.load_state_dict(m.state_dict())
    assert again.update(1.0) == m.update(1.0)  # the EMA travels with the state


def test_augmented_lagrangian_prices_cost_above_its_multiplier():
    # rho = 0.5, d = 1. Each iteration: multiplier <- max(0, mu + rho g); value = max(0, mu + rho g).
    # J_c = 3 (g 2): mu 1.0, value 2.0; J_c = 2 (g 1): mu 1.5, value 2.0;
    # J_c = 0 (g -1): mu 1.0, value 0.5; J_c = 0: mu 0.5, value 0.0; J_c = 0: mu 0, value 0.
    m = AugmentedLagrangian(cost_limit=1.0, rho=0.5)
    values, multipliers = [], []
    for c in (3.0, 2.0, 0.0, 0.0, 0.0):
        values.append(m.update(c))
        multipliers.append(m.multiplier)
    assert values == pytest.approx([2.0, 2.0, 0.5, 0.0, 0.0])
    assert multipliers == pytest.approx([1.0, 1.5, 1.0, 0.5, 0.0])


@pytest.mark.parametrize(
    "kind, cls", [("dual", DualAscent), ("regularized", RegularizedDual), ("optimistic", OptimisticDual)]
)
def test_options_build_the_named_controller_with_the_budget_scale(kind, cls):
    m = multiplier_options(kind, lr=0.1, scale="budget").build(0.25)
    assert isinstance(m, cls) and m.scale == 0.25 and m.lr == 0.1
    assert multiplier_options("augmented", lr=0.1, scale="none").build(0.25).scale == 1.0


def _controllers(algo: dict):
    from cmdp_rl import load_config
    from cmdp_rl.algos import make_algo
    from cmdp_rl.envs import make_env
    from cmdp_rl.policies import make_agent

    cfg = load_config({"algo": algo, "env": {"num_envs": 2}, "policy": {"hidden_sizes": [8]}})
    env = make_env(cfg.env)
    built = make_algo(cfg.algo, make_agent(cfg.policy, env, algo=cfg.algo))
    env.close()
    return built


@pytest.mark.parametrize(
    "algo, cls",
    [
        ({"name": "ppo_lag", "multiplier": {"kind": "optimistic", "scale": "budget"}}, OptimisticDual),
        ({"name": "trpo_lag", "multiplier": {"kind": "augmented", "scale": "budget"}}, AugmentedLagrangian),
        (
            {"name": "sac_lag", "multiplier": {"kind": "regularized", "scale": "budget"}, "buffer_size": 1000},
            RegularizedDual,
        ),
        (
            {"name": "td3_lag", "multiplier": {"kind": "optimistic", "scale": "budget"}, "buffer_size": 1000},
            OptimisticDual,
        ),
        ({"name": "sac_lag", "multiplier": {"kind": "pid", "scale": "budget"}, "buffer_size": 1000}, PIDLagrangian),
    ],
)
def test_every_lagrangian_algorithm_builds_the_chosen_update_on_the_relative_violation(algo, cls):
    built = _controllers({**algo, "cost_limit": 0.5})
    (c,) = built.multiplier.controllers
    assert isinstance(c, cls) and c.scale == pytest.approx(c.cost_limit)  # sac/td3: the discounted budget


def test_regularized_ppo_lag_adds_tau_to_the_entropy_bonus_and_the_scale_reaches_focops_and_cup():
    ppo = _controllers({"name": "ppo_lag", "multiplier": {"kind": "regularized", "tau": 0.3}, "entropy_coef": 0.01})
    assert ppo.entropy_coef == pytest.approx(0.31)
    for name in ("focops", "cup", "pid_lag"):
        m = _controllers({"name": name, "cost_limit": 0.25, "multiplier": {"scale": "budget"}}).multiplier
        m = m.controllers[0] if hasattr(m, "controllers") else m
        assert m.scale == 0.25


@pytest.mark.parametrize("kind", ["dual", "regularized", "optimistic", "augmented", "pid"])
def test_max_clamps_every_kind_and_infinity_changes_nothing(kind):
    # d = 1, scale none, J_c = 3: every kind's first step is lr * 2 = 10 (pid: kp 2 * 2 + ki 0.1 * 2), over the clamp.
    step = {} if kind == "pid" else {"lr": 5.0}  # pid's gains are its own options
    clamped = multiplier_options(kind, **step, scale="none", max=1.5).build(1.0)
    assert clamped.update(3.0) == 1.5 and clamped.update(3.0) == 1.5
    free = multiplier_options(kind, **step, scale="none").build(1.0)
    assert free.update(3.0) > 1.5


def test_log_dual_steps_log_lambda_per_finished_episode_within_floor_and_max():
    # d = 1, lr = 1, from 0.01, a whole step from a violation of a quarter of the budget (saturation 0.25):
    # J_c = 3 (g 2) with a whole window new: log lambda + 1; J_c = 1.1 (g 0.1: 0.4 of a step): + 0.4;
    # J_c = 1.5 (g 0.5), half the window new: + 0.5; J_c = 0 (g -1): - 1; again: - 1, held at the floor 0.01.
    m = LogDual(cost_limit=1.0, lr=1.0, init=0.01, floor=0.01, maximum=100.0, scale=1.0, saturation=0.25)
    seq = [m.update(3.0, 1.0), m.update(1.1, 1.0), m.update(1.5, 0.5), m.update(0.0, 1.0), m.update(0.0, 1.0)]
    want = [math.exp(1.0), math.exp(1.4), math.exp(1.9), math.exp(0.9), 1.0]
    assert seq == pytest.approx([0.01 * w for w in want])
    # saturation 1: the step in proportion to g up to J_c = 2d (J_c = 1.1: a tenth of a step)
    linear = LogDual(cost_limit=1.0, lr=1.0, init=0.01, floor=0.01, maximum=100.0, scale=1.0, saturation=1.0)
    assert [linear.update(3.0), linear.update(1.1)] == pytest.approx([0.01 * math.e, 0.01 * math.exp(1.1)])
    high = LogDual(cost_limit=1.0, lr=3.0, init=50.0, floor=0.01, maximum=100.0, scale=1.0, saturation=0.25)
    assert high.update(10.0) == pytest.approx(100.0)  # 50 e^3 > max
    with pytest.raises(ValueError, match="floor <= init <= max"):
        LogDual(cost_limit=1.0, lr=1.0, init=0.001, floor=0.01, maximum=100.0, scale=1.0, saturation=0.25)


def test_a_per_episode_multiplier_steps_once_per_episode_and_not_before_one_ends():
    make = multiplier_options("log", lr=1.0).build
    m = Multipliers(make, [1.0])
    assert m.update(EpisodeCost((3.0,), 10.0, RUNNING)) == pytest.approx([0.01])  # none has ended: no window
    # 25 episodes of a 100-episode window ended in this batch: a quarter step on the window's J_c (g 1).
    assert m.update(EpisodeCost((9.0,), 10.0, FINISHED, (3.0,), 25)) == pytest.approx([0.01 * math.exp(0.25)])
    # The same window and no episode new (a batch in the middle of long episodes): lambda stays.
    assert m.update(EpisodeCost((9.0,), 10.0, WINDOW, (3.0,), 0)) == pytest.approx([0.01 * math.exp(0.25)])
    # 400 new episodes, four windows' worth: one whole step, not four (the window's J_c is measured once).
    assert m.update(EpisodeCost((9.0,), 10.0, FINISHED, (3.0,), 400)) == pytest.approx([0.01 * math.exp(1.25)])
    assert EPISODE_WINDOW == 100
