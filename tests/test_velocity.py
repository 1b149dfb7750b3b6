"""Velocity tasks: the cost fires exactly when the task's speed exceeds its threshold.

The cost logic is checked on a fake env that reports chosen velocities (no MuJoCo needed), then on
gymnasium's real MuJoCo envs against the speed measured from the simulator state, as
Safety-Gymnasium measures it.
"""

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers.policies import ForwardPolicy

from cmdp_rl import Collector, finished_episodes, keys, load_config, train
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.envs import GymVecEnv
from cmdp_rl.envs.velocity import VELOCITY_TASKS, VelocityCost, VelocityEnvConfig, make_velocity_env

PLANAR = {"Ant", "Humanoid"}  # planar speed sqrt(vx^2 + vy^2); the others: signed x velocity


class ScriptedVelocity(gym.Env):
    """Reports the velocities of a script, one (vx, vy) pair per step, as MuJoCo locomotion envs do."""

    def __init__(self, script):
        self.script = list(script)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        vx, vy = self.script[self.t % len(self.script)]
        self.t += 1
        return np.full(1, self.t, np.float32), 1.0, False, False, {"x_velocity": vx, "y_velocity": vy}


def test_task_tables_agree():
    from typing import get_args

    assert set(get_args(VelocityEnvConfig.__pydantic_fields__["task"].annotation)) == set(VELOCITY_TASKS)
    assert {t for t, spec in VELOCITY_TASKS.items() if spec.planar} == PLANAR
    expected = {
        "Ant": 2.6222,
        "HalfCheetah": 3.2096,
        "Hopper": 0.7402,
        "Humanoid": 1.4149,
        "Swimmer": 0.2282,
        "Walker2d": 2.3415,
    }
    assert {t: spec.threshold for t, spec in VELOCITY_TASKS.items()} == expected


@pytest.mark.parametrize("task", sorted(VELOCITY_TASKS))
def test_cost_fires_exactly_above_the_threshold(task):
    spec = VELOCITY_TASKS[task]
    thr = spec.threshold
    above, below = math.nextafter(thr, math.inf), math.nextafter(thr, -math.inf)
    # (vx, vy) and whether the step costs
    script = [
        ((thr, 0.0), 0.0),  # exactly at the threshold: no cost (strict test)
        ((above, 0.0), 1.0),  # the next float above: cost
        ((below, 0.0), 0.0),
        ((0.0, 0.0), 0.0),
        ((-3 * thr, 0.0), 1.0 if task in PLANAR else 0.0),  # fast backwards: only a speed norm counts it
        ((0.0, 3 * thr), 1.0 if task in PLANAR else 0.0),  # fast sideways: only a planar speed counts it
        ((0.8 * thr, 0.8 * thr), 1.0 if task in PLANAR else 0.0),  # norm 1.13 thr, x alone below
    ]
    env = VelocityCost(ScriptedVelocity([v for v, _ in script]), spec.threshold, spec.planar)
    env.reset(seed=0)
    for (vx, vy), cost in script:
        *_, info = env.step(np.zeros(1, np.float32))
        assert info["cost"] == cost, (task, vx, vy)
        assert info["speed"] == (math.hypot(vx, vy) if task in PLANAR else vx)


def test_velocity_cost_reaches_the_batch_through_the_vector_env_and_episode_ends():
    thr = VELOCITY_TASKS["HalfCheetah"].threshold
    script = [(0.0, 0.0), (2 * thr, 0.0), (2 * thr, 0.0)]  # costs 0, 1, 1, repeating

    def make():
        return VelocityCost(gym.wrappers.TimeLimit(ScriptedVelocity(script), 3), thr, planar=False)

    env = GymVecEnv(make, 2)
    actor = ForwardPolicy(lambda obs: torch.zeros(obs.shape[0], 1))
    batch = Collector(env, actor, rollout_steps=6, seed=0).collect()
    assert batch[keys.NEXT][keys.COST][0, :, 0].tolist() == [0, 1, 1, 0, 1, 1]
    # the last step of each episode is a done step: its cost comes through gymnasium's final_info
    assert finished_episodes(batch)["cost"].tolist() == [[2.0]] * 4  # [E, K]


def test_missing_velocity_info_is_a_clear_error():
    class NoInfo(ScriptedVelocity):
        def step(self, action):
            obs, r, te, tr, _ = super().step(action)
            return obs, r, te, tr, {}

    env = VelocityCost(NoInfo([(0.0, 0.0)]), 1.0, planar=True)
    env.reset(seed=0)
    with pytest.raises(KeyError, match="x_velocity"):
        env.step(np.zeros(1, np.float32))


def test_config_selects_the_velocity_env_and_checks_its_fields():
    cfg = load_config({"env": {"name": "velocity", "task": "Hopper"}})
    assert cfg.env.task == "Hopper" and cfg.env.velocity_threshold is None and cfg.env.max_steps == 1000
    for env, field in (
        ({"task": "Dog"}, "env.task"),
        ({"backend": "torch"}, "env.backend"),
        ({"velocity_threshold": -1.0}, "env.velocity_threshold"),
        ({"max_steps": 0}, "env.max_steps"),
        ({"wall": "pass"}, "env"),  # a Reach1D option is unknown to the velocity env
    ):
        with pytest.raises(Exception) as err:
            load_config({"env": {"name": "velocity", **env}})
        assert str(err.value).startswith(field), str(err.value)


# --- on gymnasium's MuJoCo envs -----------------------------------------------------------------------


def _planar_position(env: gym.Env, task: str) -> np.ndarray:
    """The position Safety-Gymnasium differentiates: the torso (Ant), the mass centre (Humanoid),
    the root slide joints (the others)."""
    u = env.unwrapped
    if task == "Ant":
        return u.data.body("torso").xpos[:2].copy()
    if task == "Humanoid":
        mass = u.model.body_mass[:, None]
        return (mass * u.data.xipos).sum(0)[:2] / mass.sum()
    return np.array([u.data.qpos[0], u.data.qpos[1] if task == "Swimmer" else 0.0])


@pytest.mark.parametrize("task", sorted(VELOCITY_TASKS))
def test_mujoco_cost_matches_the_simulated_speed(task, tmp_path, monkeypatch):
    pytest.importorskip("mujoco")
    monkeypatch.chdir(tmp_path)  # MuJoCo writes MUJOCO_LOG.TXT (model warnings) to the working directory
    spec = VELOCITY_TASKS[task]
    env = make_velocity_env(task)
    assert isinstance(env, VelocityCost) and env.threshold == spec.threshold
    assert env.spec.max_episode_steps == 1000
    u = env.unwrapped
    # Launch the body at 3x the threshold forwards, backwards, sideways, and at rest.
    launches = {"forward": (3.0, 0.0), "backward": (-3.0, 0.0), "sideways": (0.0, 3.0), "rest": (0.0, 0.0)}
    seen = {}
    for name, (fx, fy) in launches.items():
        env.reset(seed=0)
        qpos, qvel = u.data.qpos.copy(), u.data.qvel.copy() * 0
        qvel[0] = fx * spec.threshold
        if task in ("Ant", "Humanoid", "Swimmer"):  # the root moves in the plane (free joint / two slides)
            qvel[1] = fy * spec.threshold
        u.set_state(qpos, qvel)
        before = _planar_position(env, task)
        *_, info = env.step(np.zeros(env.action_space.shape, np.float32))
        v = (_planar_position(env, task) - before) / u.dt
        speed = float(np.hypot(*v)) if task in PLANAR else float(v[0])
        assert info["speed"] == pytest.approx(speed, rel=1e-6, abs=1e-9)
        assert info["cost"] == float(speed > spec.threshold)
        seen[name] = info["cost"]
    env.close()
    assert seen["forward"] == 1.0 and seen["rest"] == 0.0
    assert seen["backward"] == (1.0 if task in PLANAR else 0.0)
    if task != "Swimmer":  # sideways launches only exist for planar roots
        assert seen["sideways"] == (1.0 if task in PLANAR else 0.0)
    else:
        assert seen["sideways"] == 0.0  # Swimmer v1 constrains the x velocity only


def test_env_velocity_turns_observation_normalization_on_by_default():
    assert compose_config(["env=velocity"]).normalize.obs
    assert not compose_config(["env=velocity", "normalize=none"]).normalize.obs
    assert not compose_config(["env=velocity", "normalize.obs=false"]).normalize.obs
    assert not compose_config(["env=reach1d"]).normalize.obs
    cfg = compose_config(["env=velocity", "env.task=Walker2d", "normalize.reward=true"])
    assert cfg.env.task == "Walker2d" and cfg.normalize.obs and cfg.normalize.reward


def test_a_short_training_run_on_halfcheetah(tmp_path, monkeypatch):
    pytest.importorskip("mujoco")
    monkeypatch.chdir(tmp_path)
    cfg = compose_config(
        [
            "env=velocity",
            "env.num_envs=2",
            "env.max_steps=40",
            "rollout_steps=40",
            "total_steps=160",
            "eval_episodes=2",
            "algo=ppo_lag",
            "algo.cost_limit=25",
            "algo.update_epochs=1",
        ]
    )
    result = train(cfg, tmp_path / "run", echo=lambda _: None)
    assert result["episodes"] == 2 and result["episode_length"] == 40.0
    assert 0.0 <= result["episode_cost"] <= 40.0
