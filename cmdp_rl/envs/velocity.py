"""Velocity-constrained MuJoCo locomotion: Safety-Gymnasium's velocity tasks on gymnasium's own v5 envs.

Each task is gymnasium's env unchanged; :class:`VelocityCost` writes ``info["cost"] = float(speed >
threshold)``, the threshold Safety-Gymnasium's v1 value, the speed as that package's code measures it
(signed forward velocity; Ant and Humanoid: planar speed), read from the env's ``info["x_velocity"]``
and ``info["y_velocity"]``. docs/benchmarks.md has the task-by-task facts and the v4/v5 differences."""

from __future__ import annotations

import importlib.util
from functools import partial
from typing import Any, Literal, NamedTuple, Optional

import gymnasium as gym
import numpy as np

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import NonNegativeFloat, PositiveInt, options
from cmdp_rl.envs.options import SAFETY_GYM_BUDGET, EnvOptions
from cmdp_rl.envs.vector import GymVecEnv, VecEnv

# planar: speed is the norm of (x_velocity, y_velocity), else the signed x_velocity
VelocityTask = NamedTuple("VelocityTask", [("threshold", float), ("planar", bool)])


# Safety-Gymnasium v1 thresholds (SafetyXVelocity-v1).
VELOCITY_TASKS: dict[str, VelocityTask] = {
    "Ant": VelocityTask(2.6222, planar=True),
    "HalfCheetah": VelocityTask(3.2096, planar=False),
    "Hopper": VelocityTask(0.7402, planar=False),
    "Humanoid": VelocityTask(1.4149, planar=True),
    "Swimmer": VelocityTask(0.2282, planar=False),
    "Walker2d": VelocityTask(2.3415, planar=False),
}


class VelocityCost(gym.Wrapper):
    """Writes ``info["cost"] = 1.0`` when the step's speed (also written, ``info["speed"]``) exceeds
    ``threshold``, else ``0.0``: ``info["x_velocity"]``, with ``planar`` the norm of it and ``y_velocity``."""

    def __init__(self, env: gym.Env, threshold: float, planar: bool) -> None:
        super().__init__(env)
        self.threshold = float(threshold)
        self.planar = planar

    def speed(self, info: dict[str, Any]) -> float:
        try:
            vx = float(info["x_velocity"])
            vy = float(info["y_velocity"]) if self.planar else 0.0
        except KeyError as exc:
            raise KeyError(
                f"VelocityCost: the wrapped env reports no info[{exc.args[0]!r}]; it needs gymnasium's MuJoCo "
                f"locomotion info (x_velocity{', y_velocity' if self.planar else ''})"
            ) from exc
        return float(np.hypot(vx, vy)) if self.planar else vx

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["speed"] = speed = self.speed(info)
        info["cost"] = 1.0 if speed > self.threshold else 0.0
        return obs, reward, terminated, truncated, info


def make_velocity_env(
    task: str, velocity_threshold: float | None = None, max_steps: int = 1000, **kwargs: Any
) -> gym.Env:
    """Gymnasium's ``<task>-v5`` with its velocity cost; ``velocity_threshold=None`` takes the task's."""
    if task not in VELOCITY_TASKS:
        raise ValueError(f"env.task must be one of {sorted(VELOCITY_TASKS)}, got {task!r}")
    if importlib.util.find_spec("mujoco") is None:
        raise ImportError("env=velocity needs MuJoCo: `pip install -e '.[mujoco]'` (or e.g. `make bench-velocity`)")
    spec = VELOCITY_TASKS[task]
    threshold = spec.threshold if velocity_threshold is None else velocity_threshold
    env = gym.make(f"{task}-v5", max_episode_steps=max_steps, **kwargs)
    return VelocityCost(env, threshold, spec.planar)


@options
class VelocityEnvConfig(EnvOptions):
    """``env=velocity``: a MuJoCo locomotion task with cost 1 on every step faster than a threshold."""

    name: str = "velocity"
    backend: Literal["gym"] = "gym"
    num_envs: PositiveInt = 8
    task: Literal[tuple(VELOCITY_TASKS)] = "HalfCheetah"
    # None: the task's Safety-Gymnasium v1 threshold (VELOCITY_TASKS); a number overrides it.
    velocity_threshold: Optional[NonNegativeFloat] = None
    max_steps: PositiveInt = 1000

    def budget(self) -> float:
        """d = 25 cost per episode, the field's budget for these tasks (``SAFETY_GYM_BUDGET``)."""
        return SAFETY_GYM_BUDGET

    def env_id(self) -> str:
        return f"{self.task}-v5"

    def render_env(self) -> gym.Env:
        """One env of this task rendering ``rgb_array`` frames of RENDER_SIZE (for video)."""
        w, h = RENDER_SIZE
        return make_velocity_env(
            self.task, self.velocity_threshold, self.max_steps, render_mode="rgb_array", width=w, height=h
        )


RENDER_SIZE = (320, 240)  # video frames (width, height): multiples of 16, as video encoders like


def make_velocity_vec_env(cfg: VelocityEnvConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    return GymVecEnv(
        partial(make_velocity_env, cfg.task, cfg.velocity_threshold, cfg.max_steps), num_envs, device=device
    )


register("env", "velocity", VelocityEnvConfig, make_velocity_vec_env)
