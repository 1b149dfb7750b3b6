"""Reach1D reproduces the seed's arithmetic exactly, float edges included.

Expected values are computed here by hand from the seed's rules (float64 state, float32 action
bound, strict crossing test, noise drawn from gymnasium's seeded generator in call order), not by
running another copy of the env.
"""

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils import seeding
from gymnasium.utils.env_checker import check_env

import cmdp_rl  # noqa: F401  (registers the env)
from cmdp_rl.envs import GymVecEnv, Reach1D

A32 = float(np.float32(0.1))  # the seed's action bound as float32: 0.10000000149011612


def hand_trajectory(actions, seed, x0=0.1, noise=0.02, wall=0.5, goal=0.9, max_steps=100, block=True):
    """The seed's rules, written out: returns (obs0, [(obs, reward, cost, term, trunc, true_x)])."""
    rng, _ = seeding.np_random(seed)
    x = x0
    obs0 = np.float32(min(max(x + rng.normal(0.0, noise), 0.0), 1.0))
    out = []
    for k, a in enumerate(actions, start=1):
        a = min(max(a, -A32), A32)
        prev = x
        prop = min(max(x + a, 0.0), 1.0)
        crossed = (prev - wall) * (prop - wall) < 0
        x = prev if (crossed and block) else prop
        dist = abs(goal - x)
        r = abs(goal - prev) - dist + (1.0 if dist < 0.02 else 0.0)
        o = np.float32(min(max(x + rng.normal(0.0, noise), 0.0), 1.0))
        out.append((o, r, 1.0 if crossed else 0.0, dist < 0.02, k >= max_steps, x))
    return obs0, out


def run_env(env, actions, seed):
    obs0, info = env.reset(seed=seed)
    assert info["true_x"] == 0.1 if env.start == 0.1 else True
    rows = []
    for a in actions:
        o, r, term, trunc, info = env.step(a)
        rows.append((o, r, info["cost"], term, trunc, info["true_x"]))
    return obs0, rows


@pytest.mark.parametrize("seed", [0, 1, 123])
def test_noisy_trajectory_matches_hand_computation(seed):
    rng = np.random.default_rng(seed)
    actions = [float(a) for a in rng.uniform(-0.15, 0.15, size=60).astype(np.float32)]
    env = Reach1D()
    obs0, rows = run_env(env, [np.array([a], dtype=np.float32) for a in actions], seed)
    h0, hand = hand_trajectory(actions, seed)
    assert obs0[0] == h0 and obs0[1] == np.float32(0.9) and obs0.dtype == np.float32
    for (o, r, c, te, tr, x), (ho, hr, hc, hte, htr, hx) in zip(rows, hand):
        assert o[0] == ho and r == hr and c == hc and te == hte and tr == htr and x == hx


def test_seed_naive_policy_numbers():
    """The seed's own __main__: always push at the float32 bound. Stopped at x ~ 0.4 by the wall."""
    env = Reach1D()
    env.reset(seed=0)
    ret, cost = 0.0, 0.0
    for _ in range(100):
        _, r, term, trunc, info = env.step(env.action_space.high)
        ret += r
        cost += info["cost"]
        if term or trunc:
            break
    assert ret == 0.30000000447034836
    assert cost == 97.0 and not term and trunc
    assert info["true_x"] == 0.1 + A32 + A32 + A32  # three moves, then blocked every step


def test_float64_edge_lands_on_wall_and_passes_free():
    """0.1 + 4 * 0.1 == 0.5 in float64: the strict test lets the next move through at no cost."""
    env = Reach1D()
    env.reset(seed=0)
    xs, costs = [], []
    for _ in range(8):
        _, r, term, trunc, info = env.step(np.array([0.1], dtype=np.float64))
        xs.append(info["true_x"])
        costs.append(info["cost"])
    assert xs[3] == 0.5 and costs == [0.0] * 8
    assert term and xs[-1] == pytest.approx(0.9, abs=1e-12)


def test_float32_bound_never_lands_on_wall():
    """From the default start, no sequence of saturated float32 moves lands on x == 0.5."""
    frontier, seen = {0.1}, {0.1}
    for _ in range(100):
        nxt = set()
        for x in frontier:
            for a in (A32, -A32):
                p = min(max(x + a, 0.0), 1.0)
                if (x - 0.5) * (p - 0.5) >= 0:  # not a crossing: the move is taken
                    nxt.add(p)
        frontier = nxt - seen
        seen |= nxt
    assert 0.5 not in seen and len(seen) < 100


def test_projects_action_path_sends_float32():
    """The toolkit's vector env casts to the env's float32 action dtype before stepping, so a float64
    0.1 from a policy is blocked at the wall like the seed's float32 bound."""
    venv = GymVecEnv(lambda: Reach1D(obs_noise=0.0), 1)
    venv.reset(seed=0)
    costs = [venv.step(torch.full((1, 1), 0.1, dtype=torch.float64)).cost.item() for _ in range(5)]
    assert costs == [0.0, 0.0, 0.0, 1.0, 1.0]
    venv.close()


def test_landing_exactly_on_wall_then_moving_is_free():
    env = Reach1D(obs_noise=0.0, start=0.5)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([-0.05], dtype=np.float32))
    assert info["cost"] == 0.0 and info["true_x"] == 0.5 - float(np.float32(0.05))


def test_wall_pass_goes_through_and_costs():
    env = Reach1D(obs_noise=0.0, wall="pass", start=0.45)
    env.reset(seed=0)
    _, r, _, _, info = env.step(np.array([0.1], dtype=np.float32))
    assert info["cost"] == 1.0 and info["true_x"] == 0.45 + A32
    assert r == abs(0.9 - 0.45) - abs(0.9 - (0.45 + A32))
    blocked = Reach1D(obs_noise=0.0, start=0.45)
    blocked.reset(seed=0)
    _, r, _, _, info = blocked.step(np.array([0.1], dtype=np.float32))
    assert info["cost"] == 1.0 and info["true_x"] == 0.45 and r == 0.0


def test_goal_terminates_with_bonus_and_time_limit_truncates():
    env = Reach1D(obs_noise=0.0, start=0.85, max_steps=3)
    env.reset(seed=0)
    _, r, term, trunc, info = env.step(np.array([0.04], dtype=np.float32))
    x = 0.85 + float(np.float32(0.04))
    assert term and not trunc and r == abs(0.9 - 0.85) - abs(0.9 - x) + 1.0
    env = Reach1D(obs_noise=0.0, max_steps=3)
    env.reset(seed=0)
    flags = [env.step(np.zeros(1, dtype=np.float32))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]


def test_observation_clipped_to_unit_interval():
    env = Reach1D(obs_noise=5.0, start=0.0)
    obs, _ = env.reset(seed=3)
    for _ in range(50):
        obs, *_ = env.step(np.zeros(1, dtype=np.float32))
        assert 0.0 <= obs[0] <= 1.0


def test_uniform_start_and_probe():
    env = Reach1D(start=[0.2, 0.3], probe=True, obs_noise=0.1)
    obs, info = env.reset(seed=4)
    rng, _ = seeding.np_random(4)
    assert info["true_x"] == rng.uniform(0.2, 0.3)
    assert obs.shape == (3,) and obs[2] == -1.0
    x = info["true_x"]
    obs, r, _, _, info = env.step(np.array([0.1, 1.0], dtype=np.float32))
    assert info["true_x"] == x and r == 0.0  # a probe makes no motion
    assert obs[2] == obs[0]  # the probe reading is recorded
    obs2, *_ = env.step(np.array([0.0, -1.0], dtype=np.float32))
    assert obs2[2] == obs[2]  # an ordinary step keeps the last probe reading


def test_registered_and_passes_gymnasium_checker():
    env = gym.make("cmdp_rl/Reach1D-v0")
    check_env(env.unwrapped)
    check_env(Reach1D(wall="pass", start=[0.0, 1.0], probe=True))
    env.close()


def test_bad_wall_mode():
    with pytest.raises(ValueError, match="env.wall"):
        Reach1D(wall="soft")
