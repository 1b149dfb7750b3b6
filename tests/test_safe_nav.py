"""env=safe_nav: Safety-Gymnasium's navigation tasks, batched, against the real tasks (env=safety_gym).

Fidelity is the contract: with the same seed (hence the same layouts) and the same actions, the
batched env's layouts, rewards, costs and episode ends equal the reference's, and its observations
are within :data:`REFERENCE` of them, over a whole episode, goals reached, hazards entered and the
automatic reset included. Exact where the arithmetic is exact on any CPU: both sides run MuJoCo's
physics, place bodies from the same draws (with the C library's cos and sin on both sides), and
compute a reward from distances over two axes (each step correctly rounded whatever the kernel: a
sum of two numbers has one order); costs and ends are events. Not the observations: the batched
lidar multiplies all objects' offsets at once where the reference goes object by object, and the
BLAS and numpy kernels picked for each shape round otherwise.
"""

import importlib.util

import numpy as np
import pytest
import torch

if importlib.util.find_spec("safety_gymnasium") is None or importlib.util.find_spec("mujoco") is None:
    pytest.skip("Safety-Gymnasium is installed by `make setup-safety-gym`", allow_module_level=True)

from helpers.runs import eval_result, metrics_rows  # noqa: E402
from helpers.tolerance import Tolerance, assert_close  # noqa: E402

from cmdp_rl import train  # noqa: E402
from cmdp_rl.config.run_config import ConfigError, compose_config  # noqa: E402
from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv  # noqa: E402
from cmdp_rl.envs.safe_nav.spec import AGENT_KEEPOUT, GOAL_KEEPOUT, HAZARD_KEEPOUT, VASE_KEEPOUT  # noqa: E402
from cmdp_rl.envs.safety_gym.env import make_task  # noqa: E402
from lab.fidelity.safe_nav_fidelity import steer as toward_goal  # noqa: E402  (the fidelity table's steering)

# The lidar in one batch against object by object (see the module's docstring); its readings lie in [0, 1], the
# other observations are MuJoCo's sensors, copied. Measured under every make test-cpus setting: 2.3e-15 apart at
# most; the lidar alone, near a bin's edge, 3.2e-14 (tests/test_safe_nav_speed.py's LIDAR): 1e-12 is 30 times that.
REFERENCE = Tolerance("safe_nav's observations against Safety-Gymnasium's", rel=0.0, abs=1e-12)


def compare(task: str, num_envs: int, steps: int, seed: int = 11, max_steps: int = 0) -> dict:
    """Step the batched env and ``num_envs`` reference envs side by side; assert equality step by
    step and return what happened (``max_steps``: shorter episodes on both sides)."""
    refs = [make_task(f"Safety{task}-v0", max_steps) for _ in range(num_envs)]
    env = SafeNavVecEnv(task, num_envs, max_steps)
    env.reset(seed=seed)
    ref_obs = np.stack([r.reset(seed=seed + i)[0] for i, r in enumerate(refs)])
    for i, r in enumerate(refs):  # the same layout from the same seed: every body placed alike
        model = r.inner.task.model
        np.testing.assert_array_equal(env.worlds.models[i].body_pos, model.body_pos)
        np.testing.assert_array_equal(env.worlds.models[i].body_quat, model.body_quat)
    assert_close(env._obs(list(range(num_envs)), env.worlds.gather(range(num_envs))), ref_obs, REFERENCE, "reset")
    rng = np.random.default_rng(0)
    seen = {"cost": 0.0, "goals": 0, "truncated": 0, "reward": 0.0, "cost_kinds": set()}
    for t in range(steps):
        action = toward_goal(env, rng)
        out = [r.step(a) for r, a in zip(refs, action)]
        s = env.step(torch.from_numpy(action))
        obs = np.stack([o[0] for o in out])
        assert_close(env.last["next_obs"], obs, REFERENCE, f"step {t}")
        np.testing.assert_array_equal(env.last["reward"], [o[1] for o in out], err_msg=f"step {t}")
        cost = np.array([o[4]["cost"] for o in out])
        np.testing.assert_array_equal(s.cost[:, 0].numpy(), cost, err_msg=f"step {t}")
        np.testing.assert_array_equal(s.terminated[:, 0].numpy(), [o[2] for o in out], err_msg=f"step {t}")
        np.testing.assert_array_equal(s.truncated[:, 0].numpy(), [o[3] for o in out], err_msg=f"step {t}")
        seen["cost"] += cost.sum()
        seen["reward"] += float(np.sum(env.last["reward"]))
        seen["goals"] += sum(o[4].get("goal_met", False) for o in out)
        seen["cost_kinds"] |= {
            k for o in out for k, v in o[4].items() if k.startswith("cost_") and k != "cost_sum" and v
        }
        for r, o in zip(refs, out):
            if o[2] or o[3]:
                seen["truncated"] += 1
                r.reset()  # the batched env resets itself, drawing the next layout from the same stream
    return seen


@pytest.mark.cpu_kernels
def test_point_goal1_equals_the_reference_over_a_whole_episode_and_the_next_reset():
    seen = compare("PointGoal1", num_envs=1, steps=1010)
    assert seen["truncated"] == 1 and seen["goals"] >= 5 and seen["cost"] >= 10  # every path was taken


@pytest.mark.cpu_kernels
def test_car_goal2_equals_the_reference_vases_included():
    seen = compare("CarGoal2", num_envs=1, steps=150, seed=3)
    assert seen["goals"] >= 1 and seen["cost"] >= 1


@pytest.mark.cpu_kernels
@pytest.mark.parametrize("task, num_envs, steps", [("PointCircle1", 1, 510), ("CarCircle2", 1, 300)])
def test_circle_equals_the_reference(task, num_envs, steps):
    """Circle: the circle reward, the sigwalls' cost (x only at level 1, x or y at level 2), the
    500-step episode and the reset after it."""
    seen = compare(task, num_envs=num_envs, steps=steps, seed=4)
    assert seen["cost"] >= 20 and seen["reward"] > 1.0 and seen["goals"] == 0
    assert seen["truncated"] == (1 if steps > 500 else 0)


@pytest.mark.cpu_kernels
def test_button_equals_the_reference():
    """Button: goal buttons pressed (reward, a new goal button, the 10-step timer blanking the
    button lidar), hazards, gremlins (mocap bodies moved before every physics step) and wrong
    buttons costing, and, with 150-step episodes, resets (each draws its layout and goal button)."""
    seen = compare("CarButton2", num_envs=1, steps=330, seed=2, max_steps=150)
    assert seen["goals"] >= 3 and seen["truncated"] == 2
    assert seen["cost_kinds"] == {"cost_hazards", "cost_gremlins", "cost_buttons"}


@pytest.mark.cpu_kernels
def test_push_equals_the_reference():
    """Push: the robot-box and box-goal reward terms, the box reaching the goal (a new goal drawn
    clear of where the robot, hazards, pillar and box are now), hazards, and a reset."""
    seen = compare("CarPush1", num_envs=1, steps=260, seed=14, max_steps=200)
    assert seen["goals"] >= 1 and seen["cost"] >= 5 and seen["truncated"] == 1


@pytest.mark.cpu_kernels
def test_an_imposed_layout_gives_the_reference_trajectory():
    """A layout taken from a reference env (not drawn from the same seed) and imposed."""
    ref = make_task("SafetyPointGoal1-v0")
    ref.reset(seed=123)
    task = ref.inner.task
    config, layout = task.world_info.world_config_dict, task.world_info.layout
    imposed = {
        "agent": layout["agent"],
        "agent_rot": config["agent_rot"],
        "goal": layout["goal"],
        "goal_rot": config["geoms"]["goal"]["rot"],
        "hazards": np.array([layout[f"hazard{k}"] for k in range(8)]),
        "hazards_rot": [config["geoms"][f"hazard{k}"]["rot"] for k in range(8)],
        "vases": np.array([layout["vase0"]]),
        "vases_rot": [config["free_geoms"]["vase0"]["rot"]],
    }
    env = SafeNavVecEnv("PointGoal1", 1)
    env.reset(seed=0)
    env._start([0], [imposed])  # env 0 starts a new episode from the reference's layout
    actions = np.random.default_rng(1).uniform(-1, 1, (100, 1, 2)).astype(np.float32)
    for action in actions:
        obs = ref.step(action[0])[0]
        env.step(torch.from_numpy(action))
        assert_close(env.last["next_obs"][0], obs, REFERENCE, "imposed layout")


@pytest.mark.parametrize("task", ["PointGoal2", "CarGoal1"])
def test_layouts_keep_their_distances(task):
    env = SafeNavVecEnv(task, 64)
    env.reset(seed=5)
    extent = env.spec.extent
    for i, layout in enumerate(env.layouts):
        objects = (
            [(layout["agent"], AGENT_KEEPOUT), (env.logic.goal[i], GOAL_KEEPOUT)]
            + [(xy, HAZARD_KEEPOUT) for xy in layout["hazards"]]
            + [(xy, VASE_KEEPOUT) for xy in layout["vases"]]
        )
        for a, (xy, keepout) in enumerate(objects):
            assert np.all(np.abs(xy) <= extent - keepout)
            for other, other_keepout in objects[a + 1 :]:
                assert np.hypot(*(xy - other)) >= keepout + other_keepout
    # 64 different layouts, drawn again identically from the same seed
    again = SafeNavVecEnv(task, 64)
    again.reset(seed=5)
    assert len({tuple(np.round(g, 9)) for g in env.logic.goal}) == 64
    np.testing.assert_array_equal(again.logic.goal, env.logic.goal)


def test_tasks_not_implemented_are_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"^env.task: 'PointRun0' is not implemented in safe_nav yet"):
        compose_config(["env=safe_nav", "env.task=PointRun0"])
    with pytest.raises(ConfigError, match=r"^env.task: 'RacecarButton1' is not implemented in safe_nav yet"):
        compose_config(["env=safe_nav", "env.task=RacecarButton1"])
    with pytest.raises(ConfigError, match=r"env.max_steps must be in \[0, 500\]"):
        compose_config(["env=safe_nav", "env.task=CarCircle1", "env.max_steps=600"])
    with pytest.raises(ConfigError, match="use env.task=CarGoal2"):
        compose_config(["env=safe_nav", "env.task=SafetyCarGoal2-v0"])


def test_ppo_lag_trains_and_a_resumed_run_equals_an_uninterrupted_one(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    base = [
        "env=safe_nav",
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


@pytest.mark.cpu_kernels
@pytest.mark.parametrize("task", ["PointGoal1", "PointCircle2", "CarButton2", "PointPush2"])
def test_threads_and_a_restored_state_give_the_same_steps(task):
    """env.threads=2 steps the same worlds in two threads; a fresh env loaded from state_dict()
    continues as the original does (goals, costs, button timers and resets included)."""
    one, two = SafeNavVecEnv(task, 4), SafeNavVecEnv(task, 4, max_steps=50, threads=2)
    one.max_steps = 50
    one.reset(seed=2), two.reset(seed=2)
    rng = np.random.default_rng(3)
    for _ in range(30):
        a = torch.from_numpy(toward_goal(two, rng))
        s1, s2 = one.step(a), two.step(a)
        for x, y in zip(s1, s2):
            assert torch.equal(x, y)
    restored = SafeNavVecEnv(task, 4, max_steps=50)
    restored.load_state_dict(two.state_dict())
    for _ in range(40):
        a = torch.from_numpy(toward_goal(two, rng))
        for x, y in zip(two.step(a), restored.step(a)):
            assert torch.equal(x, y)
    two.close()
