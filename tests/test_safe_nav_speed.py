"""env=safe_nav's speed-ups keep the numbers (docs/throughput.md, "env=safe_nav at the physics bound"):
``env.threads=2`` trains to the same metrics.csv and eval.json as one thread, bit for bit (one path);
each batched shortcut gives what it replaced: contacts and the acting step exactly (the same kernels
on the same values), the lidar of all object groups in one pass within :data:`LIDAR` of one pass per
group (the same arithmetic on arrays of another shape, which may pick other kernels)."""

import importlib.util

import numpy as np
import pytest
import torch

if importlib.util.find_spec("safety_gymnasium") is None or importlib.util.find_spec("mujoco") is None:
    pytest.skip("Safety-Gymnasium is installed by `make setup-safety-gym`", allow_module_level=True)

from helpers.runs import eval_result, metrics_rows  # noqa: E402
from helpers.tolerance import Tolerance, assert_close  # noqa: E402

from cmdp_rl import train  # noqa: E402
from cmdp_rl.config.run_config import compose_config  # noqa: E402
from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv  # noqa: E402
from cmdp_rl.envs.safe_nav.lidar import pseudo_lidar, pseudo_lidars  # noqa: E402
from cmdp_rl.policies.distributions import GaussianHead, sample  # noqa: E402
from lab.fidelity.safe_nav_fidelity import steer  # noqa: E402


@pytest.mark.cpu_kernels
def test_env_threads_2_trains_to_the_same_numbers(tmp_path):
    base = ["env=safe_nav", "env.task=PointButton1", "env.num_envs=4", "env.max_steps=30", "rollout_steps=16"]
    base += ["algo=ppo_lag", "total_steps=192", "eval_episodes=2"]
    for threads in (1, 2):
        train(compose_config([*base, f"env.threads={threads}"]), tmp_path / str(threads), echo=lambda _: None)
    assert metrics_rows(tmp_path / "1") == metrics_rows(tmp_path / "2")
    assert eval_result(tmp_path / "1") == eval_result(tmp_path / "2")


# Readings lie in [0, 1]. One pass over all groups multiplies [N, 14, 3] offsets by the robot frames where one pass
# per group multiplies [N, M, 3]: OpenBLAS picks its kernel by the shape, and its Haswell kernels (make test-cpus'
# avx2) sum the three products otherwise than its SkylakeX ones; numpy's arctan2 and hypot take a SIMD loop or libm's
# by the array's length. Measured under OPENBLAS_CORETYPE=Haswell: at most 2.1e-15 apart on these 50 draws, 3.2e-14
# over 3000 (near a bin's edge, where the angle's last-bit error is divided by the bin's width); 1e-12 is 30 times
# that, and a changed formula moves a reading by far more.
LIDAR = Tolerance("lidar, groups in one pass or one per group", rel=0.0, abs=1e-12)


@pytest.mark.cpu_kernels
def test_lidar_groups_in_one_pass_equal_one_pass_per_group():
    rng = np.random.default_rng(0)
    for _ in range(50):
        pos, mat = rng.normal(size=(16, 3)), rng.normal(size=(16, 3, 3))
        groups = [rng.uniform(-3, 3, (16, m, 2)) for m in (1, 8, 0, 1, 4)]
        together = pseudo_lidars(groups, pos, mat)
        for g, reading in zip(groups, together):
            assert_close(reading, pseudo_lidar(g, pos, mat), LIDAR, f"{g.shape[1]} objects")


@pytest.mark.cpu_kernels
@pytest.mark.parametrize("deterministic", [False, True])
def test_the_gaussian_acting_step_equals_the_distribution(deterministic):
    """Same action, same log-probability, and the same draws taken from torch's generator."""
    loc, scale = torch.randn(16, 2), torch.rand(16, 2) + 0.1
    params = {"loc": loc, "scale": scale}
    torch.manual_seed(4)
    action, log_prob = GaussianHead.act(params, deterministic)
    after = torch.randn(3)
    torch.manual_seed(4)
    dist = GaussianHead.dist(params)
    expected = sample(dist, deterministic)
    assert torch.equal(action, expected) and torch.equal(log_prob, dist.log_prob(expected))
    assert torch.equal(after, torch.randn(3))


@pytest.mark.parametrize("task", ["PointButton1", "CarGoal2", "PointPush2"])
def test_contacts_of_all_worlds_at_once_equal_a_loop_over_worlds(task):
    env = SafeNavVecEnv(task, 6)
    env.reset(seed=1)
    rng = np.random.default_rng(2)
    w = env.worlds
    for _ in range(60):
        env.step(torch.from_numpy(steer(env, rng)))
        for kind in (w.geom_is_vase, w.geom_is_gremlin, w.geom_is_pillar, w.geom_button >= 0):
            looped = []
            for d in w.datas:
                g1, g2 = d.contact.geom1, d.contact.geom2
                looped.append(bool(np.any((kind[g1] & w.geom_is_robot[g2]) | (w.geom_is_robot[g1] & kind[g2]))))
            np.testing.assert_array_equal(w.touching(kind), looped)


def test_gremlin_targets_follow_mujocos_clock():
    """The ten targets of an env step are looked up by its start time; the times in between are
    advanced in Python as MuJoCo advances ``d.time``: the same floats."""
    env = SafeNavVecEnv("CarButton1", 1)
    env.reset(seed=0)
    m, d = env.worlds.models[0], env.worlds.datas[0]
    for _ in range(300):
        start, seen = d.time, []
        for _ in range(10):
            seen.append(d.time)
            env.worlds.mj.mj_step(m, d)
        t, expected = start, []
        for _ in range(10):
            expected.append(t)
            t += m.opt.timestep
        assert seen == expected
