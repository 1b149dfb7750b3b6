"""Velocity-constrained MuJoCo locomotion: Safety-Gymnasium's velocity tasks on gymnasium's own envs.

Each task is gymnasium's MuJoCo v5 env unchanged (reward, observation, termination, time limit),
with a cost of 1 on every step whose speed exceeds the task's threshold, written to
``info["cost"]`` by :class:`VelocityCost`.

How the speed is measured, checked against Safety-Gymnasium's source
(``safety_gymnasium/tasks/safe_velocity/safety_*_velocity_v{0,1}.py``, read for facts only):

- The v1 classes change only the threshold, except Swimmer's, which overrides ``step``; every other
  v1 task runs its v0 ``step``. The cost is ``float(speed > threshold)``: strict, so a speed exactly
  at the threshold costs nothing.
- HalfCheetah, Hopper, Walker2d: speed is the signed forward velocity
  ``(qpos[0]_after - qpos[0]_before) / dt``. Running backwards never costs, however fast. (Their
  documentation writes ``abs(x_velocity)``; the code, which is what their published numbers come
  from, does not take the absolute value. We follow the code.)
- Swimmer (v1): the signed x velocity of ``qpos[0:2]``, the y velocity ignored (v0 used the planar
  norm with threshold 0.04845).
- Ant: the planar speed ``sqrt(x_vel**2 + y_vel**2)`` of the torso's position (``get_body_com("torso")``).
- Humanoid: the planar speed of the mass centre.

Gymnasium's v5 envs report exactly these quantities as ``info["x_velocity"]`` and
``info["y_velocity"]`` (Ant: the torso body ``xpos``, which is what ``get_body_com`` returns;
Humanoid: ``mass_center``; the others: ``qpos``), so the wrapper reads them from ``info`` rather than
recomputing them. The thresholds are Safety-Gymnasium's v1 values: 50% of the speed PPO reaches
after 1e7 steps, by their documentation.

One difference remains: Safety-Gymnasium builds on the v4 envs, we on v5, gymnasium 1.x's current
MuJoCo version (gymnasium's docs list the changes; Ant's default observation, for one, now includes
contact forces: 105 values instead of 27). Numbers are comparable in kind, not to the last digit.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any, Literal, Optional

import gymnasium as gym
import numpy as np

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import NonNegativeFloat, PositiveInt, options
from cmdp_rl.envs.options import SAFETY_GYM_BUDGET, EnvOptions

if TYPE_CHECKING:
    from cmdp_rl.envs.vector import VecEnv


@dataclass(frozen=True)
class VelocityTask:
    threshold: float
    planar: bool  # True: speed is the norm of (x_velocity, y_velocity); False: signed x_velocity


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
    """Writes ``info["cost"] = 1.0`` when the step's speed exceeds ``threshold``, else ``0.0``.

    Reads ``info["x_velocity"]`` (and ``info["y_velocity"]`` when ``planar``) as gymnasium's MuJoCo
    locomotion envs report them; also writes the measured ``info["speed"]``.
    """

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
        speed = self.speed(info)
        info["speed"] = speed
        info["cost"] = 1.0 if speed > self.threshold else 0.0
        return obs, reward, terminated, truncated, info


def require_mujoco() -> None:
    try:
        importlib.import_module("mujoco")
    except ImportError as exc:
        raise ImportError(
            "env=velocity needs MuJoCo: `pip install -e '.[mujoco]'` (or a make target that installs it, "
            "e.g. `make bench-velocity`)"
        ) from exc


def make_velocity_env(
    task: str, velocity_threshold: float | None = None, max_steps: int = 1000, **kwargs: Any
) -> gym.Env:
    """Gymnasium's ``<task>-v5`` with its velocity cost; ``velocity_threshold=None`` takes the task's."""
    if task not in VELOCITY_TASKS:
        raise ValueError(f"env.task must be one of {sorted(VELOCITY_TASKS)}, got {task!r}")
    require_mujoco()
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
    from cmdp_rl.envs.vector import GymVecEnv

    return GymVecEnv(
        partial(make_velocity_env, cfg.task, cfg.velocity_threshold, cfg.max_steps), num_envs, device=device
    )


register("env", "velocity", VelocityEnvConfig, make_velocity_vec_env)
