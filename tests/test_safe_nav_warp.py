"""env=safe_nav env.physics=mjwarp: MuJoCo Warp (on Warp's CPU device here) against env.physics=mujoco.

MuJoCo Warp is another implementation of the same physics (float32, its own solver), so the two
are compared within tolerances (``TOLERANCE`` in lab/fidelity/physics_compare.py; the measured
differences are in docs/safe_nav.md):
over a whole episode and the reset after it, each step started from the mujoco env's state
(``compare_physics(forced=True)``), the robot's position, rewards and lidar readings stay within
them, with the same costs and episode ends; run freely from the same start, two Point robots stay
within 2e-2 m over the first 100 steps. Warp compiles its kernels on first use, then caches them (by
default in ~/.cache/warp): with an empty cache this file took 112 s (105 s of CPU) against 20 s with
a full one, most of it each robot's first whole episode (2026-12-07, AMD EPYC, load 2.4). ``make
test`` installs MuJoCo Warp (``make setup-mjwarp``), so CI runs these. The four tasks with two envs
each are ``heavy`` (minutes): ``pytest -m heavy tests/test_safe_nav_warp.py``.
"""

import importlib.util

import numpy as np
import pytest
import torch

if importlib.util.find_spec("safety_gymnasium") is None or importlib.util.find_spec("mujoco") is None:
    pytest.skip("Safety-Gymnasium is installed by `make setup-safety-gym`", allow_module_level=True)
if importlib.util.find_spec("mujoco_warp") is None:
    pytest.skip("MuJoCo Warp is installed by `make setup-mjwarp` (the mjwarp extra)", allow_module_level=True)

from helpers.runs import eval_result, metrics_rows  # noqa: E402

from cmdp_rl import train  # noqa: E402
from cmdp_rl.config.run_config import ConfigError, compose_config  # noqa: E402
from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv  # noqa: E402
from cmdp_rl.envs.safe_nav.spec import nav_spec  # noqa: E402
from cmdp_rl.envs.safe_nav.warp_world import PER_WORLD, WARP_TASKS  # noqa: E402
from cmdp_rl.envs.safe_nav.world import NavWorlds  # noqa: E402
from lab.fidelity.physics_compare import compare_physics, tolerance_breaches  # noqa: E402
from lab.fidelity.safe_nav_fidelity import steer  # noqa: E402  (the steering the fidelity table uses)

RENDER_ONLY = ("cam_", "light_")  # camera and light fields: no physics reads them
# One for all worlds in MuJoCo Warp, and read only when sleeping is enabled (it is not here).
SLEEP_ONLY = ("dof_length",)


@pytest.mark.parametrize("task", WARP_TASKS)
def test_per_world_fields_are_all_that_a_layout_changes(task):
    """Every model field that differs between two layouts is one a Warp world holds per env (or
    one MuJoCo Warp does not have, or a camera's)."""
    import mujoco_warp

    warp_fields = {f.name for f in __import__("dataclasses").fields(mujoco_warp.Model)}
    worlds = NavWorlds(nav_spec(task), 2)
    from cmdp_rl.envs.safe_nav.layout import LayoutSampler

    sampler = LayoutSampler(worlds.spec, 2)
    sampler.seed([0, 1])
    for i in range(2):
        worlds.place(i, sampler.layout(i))
    a, b = worlds.models
    changed = {
        name
        for name in dir(a)
        if not name.startswith("_")
        and isinstance(getattr(a, name, None), np.ndarray)
        and not np.array_equal(getattr(a, name), getattr(b, name))
    }
    assert {"body_pos", "body_quat"} <= changed
    uncovered = {
        f for f in changed if f in warp_fields and f not in PER_WORLD + SLEEP_ONLY and not f.startswith(RENDER_ONLY)
    }
    assert not uncovered


def check_whole_episode(task: str, num_envs: int) -> None:
    """1010 steps (a whole episode, the automatic reset, 10 steps more), each from the mujoco env's
    state: goals reached and hazards entered at the same steps, within TOLERANCE
    (lab/fidelity/physics_compare.py: per robot, the largest one-step difference of position,
    reward, lidar and episode return; the median position difference; costs and episode ends
    equal)."""
    out = compare_physics(task, num_envs, 1010, steer, forced=True)
    assert out["episode_ends"] == num_envs and out["overflow"] == 0
    assert out["goals"] >= 5 * num_envs
    if task.endswith("1"):
        assert out["cost_steps"] > 0
    assert tolerance_breaches(out, nav_spec(task).robot) == []


@pytest.mark.parametrize("task", ["PointGoal1", "CarGoal1"])
def test_a_whole_episode_stays_within_tolerance_of_mujoco(task):
    check_whole_episode(task, 1)


@pytest.mark.heavy
@pytest.mark.parametrize("task", WARP_TASKS)
def test_every_offered_task_over_whole_episodes_of_two_envs(task):
    check_whole_episode(task, 2)


def test_free_running_trajectories_start_close():
    """Without resynchronising, the same actions keep the two Point robots close over the first 100
    steps (the Car's drift apart sooner: docs/safe_nav.md)."""
    out = compare_physics("PointGoal1", 2, 100, steer)
    assert out["pos_max_diff"] < 2e-2
    assert out["reward_max_diff"] < 1e-2


def test_a_restored_state_continues_exactly():
    """A fresh mjwarp env loaded from state_dict() continues as the original does, bit for bit
    (goals, costs and resets included)."""
    env = SafeNavVecEnv("PointGoal1", 3, max_steps=25, physics="mjwarp")
    env.reset(seed=4)
    rng = np.random.default_rng(5)
    for _ in range(20):
        env.step(torch.from_numpy(rng.uniform(-1, 1, (3, 2)).astype(np.float32)))
    restored = SafeNavVecEnv("PointGoal1", 3, max_steps=25, physics="mjwarp")
    restored.load_state_dict(env.state_dict())
    for _ in range(20):
        a = torch.from_numpy(rng.uniform(-1, 1, (3, 2)).astype(np.float32))
        for x, y in zip(env.step(a), restored.step(a)):
            assert torch.equal(x, y)
    with pytest.raises(ValueError, match="on mjwarp, this one has 3 of PointGoal1 on mujoco"):
        SafeNavVecEnv("PointGoal1", 3, max_steps=25).load_state_dict(env.state_dict())


def test_what_mjwarp_does_not_offer_is_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"^env.physics: mjwarp offers PointGoal0, .* not PointButton1"):
        compose_config(["env=safe_nav", "env.task=PointButton1", "env.physics=mjwarp"])
    with pytest.raises(ConfigError, match=r"env.physics"):
        compose_config(["env=safe_nav", "env.physics=warp"])


def test_ppo_lag_trains_on_mjwarp_and_a_resumed_run_equals_an_uninterrupted_one(tmp_path, monkeypatch):
    """`python train.py env=safe_nav env.task=PointGoal1 env.physics=mjwarp`, tiny."""
    monkeypatch.chdir(tmp_path)
    base = [
        "env=safe_nav",
        "env.task=PointGoal1",
        "env.physics=mjwarp",
        "env.num_envs=2",
        "env.max_steps=40",
        "rollout_steps=32",
        "eval_episodes=1",
        "algo=ppo_lag",
        "checkpoint_every=1",
    ]
    whole = train(compose_config([*base, "total_steps=128"]), tmp_path / "whole", echo=lambda _: None)
    assert whole["cost_limit"] == 25.0 and whole["episode_length"] == 40.0
    train(compose_config([*base, "total_steps=64"]), tmp_path / "part", echo=lambda _: None)
    train(compose_config([*base, "total_steps=128", f"resume={tmp_path / 'part'}"]), echo=lambda _: None)
    assert metrics_rows(tmp_path / "part") == metrics_rows(tmp_path / "whole")
    assert len(metrics_rows(tmp_path / "whole")) == 2
    assert eval_result(tmp_path / "part") == eval_result(tmp_path / "whole")
