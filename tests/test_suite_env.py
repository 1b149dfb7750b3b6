"""The generated suite (env=suite): instances drawn the same way every time and within their stated
ranges, the finite-horizon LP optimum against brute force, the exact valuation against episodes,
the batched env against the CMDP contract, its options, and a short learning run."""

import itertools

import numpy as np
import pytest
import torch
from scipy.optimize import linprog

from cmdp_rl import load_config, train
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.envs import check_env, make_env
from cmdp_rl.envs.suite.env import TorchSuite
from cmdp_rl.envs.suite.model import HELD_ASIDE, TUNING, FiniteCMDP, draw, evaluate, generate, solve
from cmdp_rl.envs.suite.task import SuiteConfig
from cmdp_rl.run.rundir import load_trained
from lab.studies.suite_valuation import deployed_values

MANY = range(200)


@pytest.fixture
def one_thread():
    """One torch thread, as a run uses (threads=1): thousands of tiny ops run several times slower
    on two threads of a busy machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def test_an_instance_is_the_same_every_time_it_is_drawn():
    first = generate(11)
    generate.cache_clear()
    again = generate(11)
    assert first is not again
    for field in ("P", "r", "c", "mu0", "budgets", "cost_range"):
        assert np.array_equal(getattr(first, field), getattr(again, field)), field
    assert (first.horizon, first.budget_kind) == (again.horizon, again.budget_kind)
    assert not np.array_equal(generate(12).budgets, first.budgets) or generate(12).horizon != first.horizon


def test_tuning_and_held_aside_ids_are_disjoint_sets_of_thirty():
    assert len(TUNING) == len(HELD_ASIDE) == 30 and not set(TUNING) & set(HELD_ASIDE)


def test_sizes_scales_horizons_and_budgets_span_their_ranges():
    ms = [generate(i) for i in MANY]
    horizons = [m.horizon for m in ms]
    assert 10 <= min(horizons) <= 12 and 180 <= max(horizons) <= 200
    assert {m.num_costs for m in ms} == {1, 2, 3}
    assert {m.budget_kind for m in ms} == {"mixed", "vertex", "slack"}
    rewards = np.array([m.reward_scale for m in ms])
    costs = np.concatenate([m.cost_scales for m in ms])
    for scales in (rewards, costs):
        assert scales.min() >= 1e-2 and scales.max() <= 1e2
        assert scales.min() <= 2e-2 and scales.max() >= 50  # the whole range, not a corner of it
    ratios = np.array([m.reward_scale / c for m in ms for c in m.cost_scales])
    assert ratios.min() < 1e-2 and ratios.max() > 1e2  # reward-to-cost ratios far either way
    for m in ms:
        assert np.allclose(m.P.sum(-1), 1.0) and np.isclose(m.mu0.sum(), 1.0)
        assert (m.r >= 0).all() and (m.c >= 0).all()
        lo, hi = m.cost_range.T
        assert np.all(lo - 1e-9 <= m.budgets) and np.all(m.budgets <= hi + 1e-9), m.instance
        assert np.all(m.budgets > 0)


@pytest.mark.parametrize("instance", [0, 3, 1001])
def test_the_achievable_cost_range_is_the_lps(instance):
    """The least and greatest achievable cost (backward induction) are the LP's optima of -c_k and c_k."""
    m = generate(instance)
    for k in range(m.num_costs):
        for sign, bound in ((-1.0, m.cost_range[k, 0]), (1.0, m.cost_range[k, 1])):
            flipped = FiniteCMDP(m.P, sign * m.c[k], m.c, m.mu0, m.horizon, np.full(m.num_costs, np.inf))
            assert sign * solve(flipped).ret == pytest.approx(bound, rel=1e-7)


def test_both_deterministic_and_randomised_optima_among_the_tuning_instances():
    """The LP says which: here a mixed budget gives a randomised optimum and the others a
    deterministic one (a vertex budget by construction, a slack one as the reward-optimal policy)."""
    randomised = {i: solve(generate(i)).randomised for i in TUNING}
    assert 0 < sum(randomised.values()) < len(TUNING)
    assert all(r == (generate(i).budget_kind == "mixed") for i, r in randomised.items())


def test_the_lp_optimum_is_exact_and_within_its_budgets():
    for i in (0, 9, 18, 1003):
        m = generate(i)
        opt = solve(m)
        v = evaluate(m, opt.policy)
        assert float(v.ret) == pytest.approx(opt.ret, rel=1e-6)
        assert np.all(v.costs <= m.budgets * (1 + 1e-6))
        assert len(opt.randomised_at) <= m.num_costs  # a vertex mixes in at most K (t, s) pairs


def deterministic_policies(m: FiniteCMDP) -> np.ndarray:
    """Every deterministic Markov policy ``[A^(H S), H, S, A]`` of a tiny CMDP."""
    eye = np.eye(m.num_actions)
    choices = itertools.product(range(m.num_actions), repeat=m.horizon * m.num_states)
    return np.stack([eye[list(c)].reshape(m.horizon, m.num_states, m.num_actions) for c in choices])


@pytest.mark.parametrize("seed, kind, costs", [(1, "mixed", 1), (2, "mixed", 2), (3, "vertex", 1), (4, "slack", 1)])
def test_the_lp_agrees_with_brute_force_on_tiny_instances(seed, kind, costs):
    """J* is the best mixture of deterministic policies within the budgets (the occupancy polytope
    is their convex hull: Altman 1999, ch. 3), found here by enumerating them all; where the LP's
    optimum is randomised, every deterministic policy within budget is strictly worse."""
    m = draw(np.random.default_rng(seed), 2, 2, 3, kind, cost_scales=np.ones(costs))
    each = evaluate(m, deterministic_policies(m))
    mix = linprog(
        -each.ret, A_ub=each.costs.T, b_ub=m.budgets, A_eq=np.ones((1, len(each.ret))), b_eq=[1.0], method="highs"
    )
    opt = solve(m)
    assert -mix.fun == pytest.approx(opt.ret, rel=1e-7)
    within = np.all(each.costs <= m.budgets + 1e-12, axis=1)
    best_deterministic = each.ret[within].max()
    assert best_deterministic <= opt.ret * (1 + 1e-9)
    if opt.randomised:
        assert best_deterministic < opt.ret * (1 - 1e-4)
    else:
        assert best_deterministic == pytest.approx(opt.ret, rel=1e-7)
    assert opt.randomised == (kind == "mixed")


def run_table(env: TorchSuite, table: np.ndarray, episodes: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Episode returns ``[E]`` and costs ``[E, K]`` of the table policy ``pi[t, s, a]`` on ``env``,
    whose envs each play one episode (``episodes`` = num_envs)."""
    gen = torch.Generator().manual_seed(seed)
    probs = torch.as_tensor(table)
    obs = env.reset(seed=seed)
    ret, cost = torch.zeros(episodes, dtype=torch.float64), torch.zeros(episodes, env.num_costs, dtype=torch.float64)
    for t in range(env.horizon):
        s = obs[:, : env.cmdp.num_states].argmax(-1)
        assert torch.all(obs[:, env.cmdp.num_states + t] == 1)
        a = torch.multinomial(probs[t, s], 1, generator=gen)
        step = env.step(a)
        ret += step.reward[:, 0]
        cost += step.cost
        obs = step.obs
        assert bool(step.terminated.all()) == (t == env.horizon - 1) and not step.truncated.any()
    return ret.numpy(), cost.numpy()


@pytest.mark.parametrize("instance", [0, 1])
def test_the_exact_valuation_agrees_with_episodes(instance, one_thread):
    m = generate(instance)
    table = np.random.default_rng(instance).dirichlet(np.ones(m.num_actions), size=(m.horizon, m.num_states))
    exact = evaluate(m, table)
    episodes = 4000
    ret, cost = run_table(TorchSuite(m, episodes), table, episodes, seed=5)
    z = lambda x, mean: abs(x.mean(0) - mean) / (x.std(0) / np.sqrt(episodes))  # noqa: E731
    assert z(ret, exact.ret) < 4.5
    assert np.all(z(cost, exact.costs) < 4.5)


def test_the_env_keeps_the_contract_and_names_its_costs():
    cfg = SuiteConfig(instance=0)
    env = make_env(cfg, 4)
    found = check_env(env, steps=2 * cfg.model().horizon, seed=3)
    assert found.num_costs == 3 and found.cost_names == ("cost_0", "cost_1", "cost_2")
    assert env.obs_dim == cfg.model().num_states + cfg.model().horizon + 1


def test_a_saved_env_state_continues_the_same_stream():
    m = generate(1)
    a, b = TorchSuite(m, 8), TorchSuite(m, 8)
    a.reset(seed=2)
    act = torch.zeros(8, 1, dtype=torch.long)
    for _ in range(5):
        a.step(act)
    b.load_state_dict(a.state_dict())
    for _ in range(20):
        x, y = a.step(act), b.step(act)
        assert torch.equal(x.obs, y.obs) and torch.equal(x.cost, y.cost)


@pytest.mark.parametrize(
    "env, field",
    [({"instance": -1}, "env.instance"), ({"instance": 1.5}, "env.instance"), ({"num_envs": 0}, "env.num_envs")],
)
def test_bad_options_stop_in_one_line_naming_the_field(env, field):
    with pytest.raises(ConfigError) as err:
        load_config({"env": {"name": "suite", **env}, "algo": {"name": "ppo_lag"}})
    assert str(err.value).startswith(field) and "\n" not in str(err.value)


def test_the_tasks_budget_is_the_instances():
    one, three = SuiteConfig(instance=1), SuiteConfig(instance=0)
    assert one.budget() == pytest.approx(float(generate(1).budgets[0]))
    assert three.budget() == pytest.approx(list(generate(0).budgets))


def test_a_short_ppo_lag_run_learns_an_easy_instance(tmp_path, quiet):
    """Instance 1 (K = 1, H = 13, the reward about 9 times the cost's scale): a short run with default
    options closes most of the gap from the initial policy to J*, within budget, and the summary
    prints J*."""
    lines = []
    cfg = load_config({"env": {"name": "suite", "instance": 1}, "algo": {"name": "ppo_lag"}, "total_steps": 40_000})
    train(cfg, tmp_path, echo=lines.append)
    opt = cfg.env.solve(cfg.algo.cost_limit)
    assert any(f"constrained optimum {opt.ret:.3f} (exact solver)" in line for line in lines), lines
    trained = load_trained(tmp_path)
    trained.env.close()
    model = cfg.env.model()
    start = evaluate(model, np.full((model.num_states, model.num_actions), 1 / model.num_actions))
    got = deployed_values(trained.agent, model, cfg.eval_deterministic)
    assert float(got.ret) - float(start.ret) >= 0.8 * (opt.ret - float(start.ret)), (got.ret, start.ret, opt.ret)
    assert got.costs[0] <= 1.02 * opt.budgets[0]  # the suite's verdict: at most 2% over
