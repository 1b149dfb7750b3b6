"""The fork (env=fork): the batched env against its tabular arrays, its exact optimum (the
occupancy LP) and why that optimum is randomised, its options, and the end-of-run summary's
exact optimum for K = 1 and K = 2."""

import numpy as np
import pytest
import torch

from cmdp_rl import load_config, train
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.envs.fork.env import TorchFork
from cmdp_rl.envs.fork.model import ADVANCE, GOAL, fork_cmdp
from cmdp_rl.envs.grid.optimum import solve_constrained
from cmdp_rl.envs.grid.tabular import evaluate
from lab.studies.grid_policy import value_iteration


def route_policy(model, route: int) -> np.ndarray:
    """Take ``route`` at the fork and advance everywhere: the deterministic policy of one route."""
    pi = np.zeros((model.num_states, 3))
    pi[:, ADVANCE] = 1.0
    pi[0] = np.eye(3)[route]
    return pi


def test_each_route_by_hand():
    """Route r reaches the goal after lengths[r] moves if none of the lengths[r] - 1 end draws
    before it ends the episode: return 10 * 0.9^(n-1); its hazard cells cost 1 per arrival, the
    i-th after i moves: sum_{i<n-1} 0.9^i (route 2 has none)."""
    m = fork_cmdp(num_costs=2)
    for route, n in enumerate((3, 5, 8)):
        v = evaluate(m, route_policy(m, route))
        hazard = sum(0.9**i for i in range(n - 1))
        assert v.ret == pytest.approx(10 * 0.9 ** (n - 1), rel=1e-12)
        assert v.costs == pytest.approx([hazard * (route == 0), hazard * (route == 1)], rel=1e-12)
    one = fork_cmdp(num_costs=1)
    assert one.cost_names == ("hazard",) and np.array_equal(one.c[0], m.c.sum(0))


def test_optimum_k1_mixes_the_short_and_the_safe_route_at_the_fork():
    """d = 1: route 0 costs 1.9 (over), route 2 costs 0 (within, return 4.78): the LP takes route 0
    with probability 1 / 1.9 = 10/19 and route 2 otherwise, spending the whole budget; its return
    6.529 is 37% above the best deterministic feasible route's."""
    m = fork_cmdp(num_costs=1)
    opt = solve_constrained(m, 1.0)
    assert opt.policy[0] == pytest.approx([10 / 19, 0.0, 9 / 19], abs=1e-9)
    assert opt.costs == pytest.approx([1.0])
    j0, j2 = 10 * 0.9**2, 10 * 0.9**7
    assert opt.ret == pytest.approx(10 / 19 * j0 + 9 / 19 * j2, rel=1e-9) == pytest.approx(6.528775, abs=1e-6)
    feasible = [evaluate(m, route_policy(m, r)) for r in range(3)]
    assert max(v.ret for v in feasible if v.costs[0] <= 1.0) / opt.ret < 0.74


def test_the_budget_binds_between_two_deterministic_policies():
    """The reason the optimum is randomised: at the LP's multiplier lambda*, the Lagrangian
    r - lambda c has deterministic maximisers on both sides of the budget. Just below lambda* the
    greedy policy takes the short route (cost 1.9 > d), just above it the safe one (cost 0 < d);
    no deterministic policy meets d with equality, so the optimum mixes the two."""
    m = fork_cmdp(num_costs=1)
    opt = solve_constrained(m, 1.0)
    (lam,) = opt.multipliers
    assert lam == pytest.approx((10 * 0.9**2 - 10 * 0.9**7) / 1.9, rel=1e-9)  # the exchange rate of the two routes
    below = value_iteration(m, reward=m.r - (lam - 1e-3) * m.c[0]).of_policy
    above = value_iteration(m, reward=m.r - (lam + 1e-3) * m.c[0]).of_policy
    assert below.costs[0] == pytest.approx(1.9) and above.costs[0] == 0.0
    assert below.ret > opt.ret > above.ret


def test_optimum_k2_randomises_among_all_three_routes():
    """Two budgets d = [1, 1]: both bind (multipliers > 0) and the fork's policy has three actions
    in its support (an LP vertex randomises in at most K + 1 actions of one state here)."""
    m = fork_cmdp(num_costs=2)
    opt = solve_constrained(m, [1.0, 1.0])
    assert opt.costs == pytest.approx([1.0, 1.0])
    assert (opt.multipliers > 0.1).all()
    assert (opt.policy[0] > 0.1).all() and opt.policy[0].sum() == pytest.approx(1.0)
    assert opt.ret == pytest.approx(7.045795, abs=1e-6)


def test_batched_env_steps_the_tables():
    """Every (state, action) from every state at once: next observation, reward, cost and the goal
    as the model's tables say; waiting on a hazard cell costs again; the random end ends episodes
    at about end_prob per step and the ended envs restart at the fork."""
    m = fork_cmdp(num_costs=2)
    env = TorchFork(m, num_envs=m.num_states * 3)
    env.reset(seed=0)
    s = torch.arange(m.num_states).repeat_interleave(3)
    a = torch.arange(3).repeat(m.num_states)
    env.state = s.clone()
    step = env.step(a.view(-1, 1))
    nxt = torch.as_tensor(m.next_state)[s, a]
    landed = step.next_obs.argmax(-1)
    assert torch.equal(torch.where(nxt == GOAL, m.num_states, nxt), landed)
    assert torch.equal(step.reward[:, 0], torch.as_tensor(m.r, dtype=torch.float32)[s, a])
    assert torch.equal(step.cost, torch.as_tensor(m.c, dtype=torch.float32)[:, s, a].T)
    assert bool(step.terminated[nxt == GOAL].all()) and not step.truncated.any()
    assert bool((step.obs[step.terminated[:, 0]].argmax(-1) == 0).all())
    # the random end: over many steps, terminations without the goal at about end_prob
    env = TorchFork(m, num_envs=4096)
    env.reset(seed=1)
    ended = sum(env.step(torch.ones(4096, 1, dtype=torch.int64)).terminated.float().mean().item() for _ in range(5))
    assert ended / 5 == pytest.approx(0.1, abs=0.01)  # waiting never reaches the goal


def test_monte_carlo_episodes_match_exact_values():
    """A randomised policy rolled out in the env: the mean episode return and costs are its exact
    values within 4 standard errors."""
    m = fork_cmdp(num_costs=2)
    pi = np.full((m.num_states, 3), 0.2)
    pi[:, ADVANCE] = 0.6
    pi[0] = [0.5, 0.3, 0.2]
    exact = evaluate(m, pi)
    n = 4096
    env = TorchFork(m, num_envs=n)
    obs = env.reset(seed=3)
    g = torch.Generator().manual_seed(4)
    table = torch.as_tensor(pi)
    totals, ret, cost, done_any = [], torch.zeros(n), torch.zeros(n, 2), torch.zeros(n, dtype=torch.bool)
    while not done_any.all():
        a = torch.multinomial(table[obs.argmax(-1)], 1, generator=g)
        step = env.step(a)
        ret, cost = ret + step.reward[:, 0], cost + step.cost
        first = step.terminated[:, 0] & ~done_any
        totals += [(ret[i].item(), *cost[i].tolist()) for i in first.nonzero()[:, 0]]
        done_any |= step.terminated[:, 0]
        obs = step.obs
    t = np.array(totals)
    for col, want in zip(t.T, [exact.ret, *exact.costs]):
        assert abs(col.mean() - want) < 4 * col.std() / np.sqrt(len(col)), (col.mean(), want)


def test_state_dict_continues_the_same_stream():
    m = fork_cmdp()
    env = TorchFork(m, num_envs=8)
    env.reset(seed=5)
    act = torch.zeros(8, 1, dtype=torch.int64)
    env.step(act)
    saved = env.state_dict()
    a = [env.step(act) for _ in range(6)]
    other = TorchFork(m, num_envs=8)
    other.reset(seed=99)
    other.load_state_dict(saved)
    b = [other.step(act) for _ in range(6)]
    for x, y in zip(a, b):
        assert all(torch.equal(u, v) for u, v in zip(x, y))


@pytest.mark.parametrize(
    "env, message",
    [
        ({"num_costs": 3}, "env.num_costs must be one of (1, 2), got 3"),
        ({"lengths": [1, 2]}, "env.lengths must be three positive move counts"),
        ({"end_prob": 1.0}, "env.end_prob"),
    ],
)
def test_bad_options_are_one_line(env, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_config({"env": {"name": "fork", **env}})


@pytest.mark.parametrize("num_costs, budget, optimum", [(1, 1.0, "6.529"), (2, [1.0, 1.0], "7.046")])
def test_summary_compares_with_the_exact_optimum(tmp_path, num_costs, budget, optimum):
    lines = []
    cfg = {
        "env": {"name": "fork", "num_costs": num_costs},
        "algo": {"name": "ppo_lag", "cost_limit": budget},
        "total_steps": 2048,
        "eval_episodes": 32,
        "eval_deterministic": False,
    }
    train(load_config(cfg), tmp_path, echo=lines.append)
    assert any(f"constrained optimum {optimum} (exact solver)" in line for line in lines), lines
