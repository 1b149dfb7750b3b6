"""The two-hazard gridworld: the gym env against its tabular arrays, exact evaluation against hand
computation, and the occupancy LP's optimum, multipliers and KKT conditions."""

import itertools

import gymnasium as gym
import numpy as np
import pytest

from cmdp_rl.envs.grid.env import COST_NAMES, DEFAULT_BUDGETS, GRID_ID, GridWorld, parse_layout
from cmdp_rl.envs.grid.optimum import InfeasibleBudgets, solve_constrained
from cmdp_rl.envs.grid.tabular import evaluate, grid_cmdp
from lab.studies.grid_policy import value_iteration

SMALL = ("SaG", ".b.", "...")  # 8 states: 4^8 = 65536 deterministic policies, enumerable
SMALL_KW = dict(slip=0.1, end_prob=0.1)


@pytest.fixture(scope="module")
def default():
    return grid_cmdp()


@pytest.fixture(scope="module")
def small_enumerated():
    m = grid_cmdp(SMALL, **SMALL_KW)
    choices = np.array(list(itertools.product(range(m.num_actions), repeat=m.num_states)))
    return m, evaluate(m, np.eye(m.num_actions)[choices])


# --- the gym env is the tabular CMDP ------------------------------------------------------------


def test_registered_env_starts_at_s_with_a_one_hot_observation():
    env = gym.make(GRID_ID)
    obs, info = env.reset(seed=0)
    lay = env.unwrapped.layout
    assert env.action_space == gym.spaces.Discrete(4)
    assert obs.dtype == np.float32 and obs.shape == (lay.num_cells,) and obs.sum() == 1.0
    assert lay.cells[int(np.argmax(obs))] == (2, 0) == lay.cells[info["cell"]]  # 'S' of the default layout
    assert env.unwrapped.cost_names == COST_NAMES == ("hazard_a", "hazard_b")
    assert env.unwrapped.default_budgets == DEFAULT_BUDGETS
    assert env.spec.max_episode_steps is None  # the random end is the only end besides the goal


def test_sampled_transitions_rewards_and_costs_equal_the_tabular_arrays(default):
    """From every state under every action: where the env lands is distributed as ``arrive`` (every
    frequency within 5 binomial standard deviations, never a cell of probability 0), the reward is 1
    exactly at the goal, the cost is the landing cell's hazard kinds, and the episode ends at the
    goal or with probability end_prob."""
    env = GridWorld()
    env.reset(seed=1)
    lay, n = env.layout, 300
    ended = not_goal = 0
    for s, cell in enumerate(default.state_cells):
        for a in range(4):
            counts = np.zeros(lay.num_cells)
            for _ in range(n):
                env.cell = int(cell)
                obs, reward, terminated, truncated, info = env.step(a)
                landed = int(np.argmax(obs))
                counts[landed] += 1
                assert landed == env.cell == info["cell"]
                assert reward == float(landed == lay.goal) and not truncated
                np.testing.assert_array_equal(info["cost"], lay.hazards[:, landed])
                if landed != lay.goal:
                    not_goal += 1
                    ended += terminated
                else:
                    assert terminated
            p = default.arrive[s, a]
            assert (counts[p == 0] == 0).all()
            sd = np.sqrt(p * (1 - p) / n)
            assert np.all(np.abs(counts / n - p) <= 5 * sd + 1e-12), (s, a, counts / n, p)
    assert ended / not_goal == pytest.approx(env.end_prob, abs=5 * np.sqrt(0.05 * 0.95 / not_goal))
    # and the arrays hold what the arrivals imply
    np.testing.assert_allclose(default.r, default.arrive[:, :, lay.goal])
    np.testing.assert_allclose(default.c[1], default.arrive @ lay.hazards[1])
    np.testing.assert_allclose(default.arrive.sum(-1), 1.0)


def test_episode_totals_of_the_gym_env_are_the_discounted_values_the_lp_optimises(default):
    """The random end makes the expected undiscounted episode return and costs equal to the
    gamma-discounted values: run the LP's randomised policy in the env and compare."""
    opt = solve_constrained(default, DEFAULT_BUDGETS)
    env = GridWorld()
    env.reset(seed=2)
    rng = np.random.default_rng(3)
    state_of = {int(c): s for s, c in enumerate(default.state_cells)}
    totals = []
    for _ in range(2500):
        obs, _ = env.reset()
        ret, cost, done = 0.0, np.zeros(2), False
        while not done:
            s = state_of[int(np.argmax(obs))]
            obs, r, terminated, truncated, info = env.step(rng.choice(4, p=opt.policy[s]))
            ret, cost, done = ret + r, cost + info["cost"], terminated or truncated
        totals.append([ret, *cost])
    totals = np.array(totals)
    mean, se = totals.mean(0), totals.std(0) / np.sqrt(len(totals))
    expected = np.array([opt.ret, *opt.costs])
    assert np.all(np.abs(mean - expected) < 4 * se), (mean, expected, se)


# --- exact evaluation, by hand -------------------------------------------------------------------


def test_exact_evaluation_matches_hand_computed_corridors():
    right = np.eye(4)[[1]]
    # "SG", slip 0: right reaches the goal at step 0 -> J = 1; staying (left) never does -> 0.
    m = grid_cmdp(("SG",), slip=0.0, end_prob=0.5)
    assert evaluate(m, right).ret == pytest.approx(1.0)
    assert evaluate(m, np.eye(4)[[3]]).ret == pytest.approx(0.0)
    # A slip in a one-row corridor bumps into the border: success 0.8 a step, so
    # J = sum_t gamma^t 0.2^t 0.8 = 0.8 / (1 - 0.2 gamma).
    m = grid_cmdp(("SG",), slip=0.2, end_prob=0.1)
    assert evaluate(m, right).ret == pytest.approx(0.8 / (1 - 0.2 * 0.9), abs=1e-12)
    # "SaG", slip 0: cost a on step 0, the goal on step 1 -> J = gamma, J_c = (1, 0).
    m = grid_cmdp(("SaG",), slip=0.0, end_prob=0.25)
    v = evaluate(m, np.eye(4)[[1, 1]])
    assert v.ret == pytest.approx(0.75) and v.costs == pytest.approx([1.0, 0.0])
    # shuttling S -> a -> S -> ...: cost 1 on every step that lands on 'a'. From S those are the
    # even steps, sum gamma^2t = 1 / (1 - gamma^2); from 'a', the odd ones: gamma / (1 - gamma^2).
    v = evaluate(m, np.eye(4)[[1, 3]])
    g = 0.75
    assert v.cost_value[0, m.state_of_cell(0)] == pytest.approx(1 / (1 - g**2), abs=1e-12)
    assert v.cost_value[0, m.state_of_cell(1)] == pytest.approx(g / (1 - g**2), abs=1e-12)
    assert v.ret == 0.0 and v.costs[1] == 0.0


def test_value_iteration_is_the_best_deterministic_policy(small_enumerated):
    m, v = small_enumerated
    opt = value_iteration(m)
    assert opt.of_policy.ret == pytest.approx(v.ret.max(), abs=1e-10)
    # optimal in every state, not only from the start
    assert np.all(opt.value >= v.value.max(0) - 1e-10)


# --- the LP --------------------------------------------------------------------------------------


@pytest.mark.parametrize("budgets", [(0.1, 0.1), (0.2, 0.05), (0.5, 0.3), (0.05, 0.5), (0.3, 10.0)])
def test_lp_optimum_is_at_least_every_feasible_deterministic_policy(small_enumerated, budgets):
    m, v = small_enumerated
    opt = solve_constrained(m, budgets)
    feasible = (v.costs <= np.asarray(budgets) + 1e-12).all(-1)
    assert feasible.any()
    assert opt.ret >= v.ret[feasible].max() - 1e-10
    assert np.all(opt.costs <= np.asarray(budgets) + 1e-9)
    # the LP's policy, evaluated exactly, is worth what the LP says
    got = evaluate(m, opt.policy)
    assert got.ret == pytest.approx(opt.ret, abs=1e-9) and got.costs == pytest.approx(opt.costs, abs=1e-9)


def test_randomisation_beats_every_deterministic_policy_when_both_constraints_bind(small_enumerated):
    m, v = small_enumerated
    opt = solve_constrained(m, (0.1, 0.1))
    feasible = (v.costs <= 0.1 + 1e-12).all(-1)
    assert opt.ret > v.ret[feasible].max() + 0.2  # 0.548 against 0.272
    visited = opt.occupancy.sum(1) > 1e-12
    randomised = visited & (opt.policy.max(1) < 1 - 1e-9)
    assert 1 <= randomised.sum() <= 2  # a vertex randomises in at most K states (Altman 1999)


def test_lp_with_huge_budgets_is_the_value_iteration_optimum(default, small_enumerated):
    for m in (default, small_enumerated[0]):
        unconstrained = value_iteration(m).of_policy
        for budgets in ((1e6, 1e6), np.inf):
            opt = solve_constrained(m, budgets)
            assert opt.ret == pytest.approx(unconstrained.ret, abs=1e-9)
            assert np.all(opt.multipliers == 0.0)


def test_infeasible_budgets_are_reported():
    # S has a hazard on each side: every action at S may slip onto one of them
    m = grid_cmdp(("Sa.", "b.G"), slip=0.2, end_prob=0.1)
    with pytest.raises(InfeasibleBudgets, match="no policy meets the budgets"):
        solve_constrained(m, (0.0, 0.0))
    assert solve_constrained(m, (10.0, 10.0)).ret > 0


@pytest.mark.parametrize("budgets", list(itertools.product([0.1, 0.3, 0.6, 1.0], [0.05, 0.15, 0.3, 1.0])))
def test_a_multiplier_is_positive_exactly_when_its_constraint_binds(default, budgets):
    opt = solve_constrained(default, budgets)
    binds = opt.costs >= np.asarray(budgets) - 1e-9
    np.testing.assert_array_equal(opt.multipliers > 1e-7, binds)


def test_multipliers_are_the_optimum_s_sensitivity_to_the_budgets(default):
    d, eps = np.array(DEFAULT_BUDGETS), 1e-4
    opt = solve_constrained(default, d)
    for k in range(2):
        moved = solve_constrained(default, d + eps * np.eye(2)[k])
        assert (moved.ret - opt.ret) / eps == pytest.approx(opt.multipliers[k], rel=1e-4)


@pytest.mark.parametrize("budgets", [DEFAULT_BUDGETS, (0.3, 1.0), (1.0, 0.15), (0.1, 0.05)])
def test_kkt_conditions_hold(default, budgets):
    d = np.asarray(budgets)
    opt = solve_constrained(default, d)
    lam = opt.multipliers
    assert np.all(opt.costs <= d + 1e-9)  # primal feasibility
    assert np.all(lam >= 0)  # dual feasibility
    np.testing.assert_allclose(lam * (d - opt.costs), 0.0, atol=1e-9)  # complementary slackness
    # stationarity: pi* is optimal for the Lagrangian MDP with reward r - lambda.c, whose optimal
    # values are the LP's flow duals where pi* goes (elsewhere the duals only bound them from
    # above: v >= T v there); and strong duality: J* = max_pi L(pi, lambda) + lambda.d
    lagrangian = value_iteration(default, reward=default.r - np.einsum("k,ksa->sa", lam, default.c))
    visited = opt.occupancy.sum(1) > 1e-12
    np.testing.assert_allclose(opt.lagrangian_values[visited], lagrangian.value[visited], atol=1e-8)
    assert np.all(opt.lagrangian_values >= lagrangian.value - 1e-8)
    star = evaluate(default, opt.policy)
    assert star.ret - lam @ star.costs == pytest.approx(default.mu0 @ lagrangian.value, abs=1e-9)
    assert opt.ret == pytest.approx(default.mu0 @ lagrangian.value + lam @ d, abs=1e-9)


def test_default_grid_constrained_optimum_lies_strictly_between_and_both_constraints_matter(default):
    """The figures docs/grid.md quotes."""
    unconstrained = value_iteration(default).of_policy
    safe = solve_constrained(default, (0.0, 0.0))
    opt = solve_constrained(default, DEFAULT_BUDGETS)
    only_b = solve_constrained(default, (np.inf, DEFAULT_BUDGETS[1]))
    only_a = solve_constrained(default, (DEFAULT_BUDGETS[0], np.inf))
    assert unconstrained.ret == pytest.approx(0.7362, abs=1e-4)
    assert unconstrained.costs == pytest.approx([0.8865, 0.3732], abs=1e-4)
    assert safe.ret == pytest.approx(0.5276, abs=1e-4)
    assert opt.ret == pytest.approx(0.6255, abs=1e-4)
    assert opt.multipliers == pytest.approx([0.1641, 0.3046], abs=1e-4)
    assert only_b.ret == pytest.approx(0.6921, abs=1e-4) and only_a.ret == pytest.approx(0.6835, abs=1e-4)
    assert safe.ret < opt.ret < min(only_a.ret, only_b.ret) and max(only_a.ret, only_b.ret) < unconstrained.ret
    # the optimum mixes the three routes at the start: up (over the top), right (through 'a'), down
    start = default.state_of_cell(default.layout.starts[0])
    assert opt.policy[start] == pytest.approx([0.416, 0.325, 0.259, 0.0], abs=1e-3)
    # each first move at S, then pi*: return and costs (the docs' second table)
    v = evaluate(default, opt.policy)
    q_ret = default.r[start] + default.gamma * default.P[start] @ v.value
    q_cost = default.c[:, start].T + default.gamma * default.P[start] @ v.cost_value.T
    np.testing.assert_allclose(q_ret, [0.6018, 0.7198, 0.5454, 0.5912], atol=1e-4)
    np.testing.assert_allclose(
        q_cost, [[0.0588, 0.2019], [0.8013, 0.1893], [0.0588, 0.0171], [0.2565, 0.1385]], atol=1e-4
    )


@pytest.mark.parametrize(
    "layout, match",
    [
        (("S.", "G"), "equal length"),
        (("SxG",), "unknown character"),
        (("S..",), "exactly one 'G'"),
    ],
)
def test_bad_layouts_are_refused(layout, match):
    with pytest.raises(ValueError, match=match):
        parse_layout(layout)
