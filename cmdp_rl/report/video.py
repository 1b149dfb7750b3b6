"""Videos of a trained policy (``evaluate.py run=<dir> video=true``) through gymnasium's ``RecordVideo`` (moviepy:
``pip install 'cmdp_rl[video]'``), on the env its options' ``render_env()`` gives. Headless MuJoCo: with no
``DISPLAY`` and no ``MUJOCO_GL`` this sets ``MUJOCO_GL=egl`` (software through Mesa without a GPU:
:data:`HEADLESS_GL`); MuJoCo reads it when imported, so one naming a missing library breaks ``import cmdp_rl``."""

from __future__ import annotations

import contextlib
import gc
import importlib.util
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import gymnasium as gym
import numpy as np
import torch

from cmdp_rl.config.validation import ConfigError
from cmdp_rl.deploy.policy import DeployedPolicy
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout.actions import to_env

VIDEO_MISSING = "video=true needs moviepy (gymnasium's RecordVideo writes with it): pip install 'cmdp_rl[video]'"
HEADLESS_GL = (
    "headless MuJoCo rendering needs EGL (Debian: apt-get install libegl1 libopengl0 "
    "libgl1-mesa-dri) or MUJOCO_GL=osmesa (libosmesa6)"
)


class VideoError(RuntimeError):
    """The env cannot render here (a missing package or OpenGL library)."""


@dataclass
class VideoEpisode:
    path: Path
    frames: int
    episode_return: float
    episode_cost: float | tuple[float, ...]  # one number, or one per constraint when the env has K > 1


def _headless_gl() -> None:
    """MuJoCo's renderer reads ``MUJOCO_GL`` when it opens a context: pick EGL when there is no display."""
    if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
        os.environ["MUJOCO_GL"] = "egl"


def make_render_env(env_cfg: Any) -> gym.Env:
    """One env of ``env_cfg`` rendering ``rgb_array`` frames, one rendered already: else one line now."""
    if importlib.util.find_spec("moviepy") is None:
        raise ConfigError(f"video: {VIDEO_MISSING}")
    make = getattr(env_cfg, "render_env", None)
    if make is None:
        raise ConfigError(
            f"video: env={env_cfg.name} cannot render (its options declare no render_env); "
            "videos are made for env=reach1d, env=velocity, env=safety_gym and env=gym envs with an rgb_array mode"
        )
    _headless_gl()
    try:
        env = make()
    except TypeError as exc:  # gymnasium passes render_mode to a constructor that may not take it
        raise ConfigError(f"video: env={env_cfg.name} cannot render ({exc})") from exc
    if env.render_mode != "rgb_array" or "rgb_array" not in env.metadata.get("render_modes", ()):
        env.close()
        raise ConfigError(
            f"video: env={env_cfg.name} cannot render rgb_array frames "
            f"(its render modes: {env.metadata.get('render_modes', [])})"
        )
    env.reset(seed=0)  # re-seeded by the recording; rendering draws no random numbers
    failure = None
    with _unraisable_ignored():  # gymnasium's half-built MuJoCo viewer raises in __del__ when collected
        try:
            frame = env.render()
        except Exception as exc:  # noqa: BLE001 - OpenGL's failures come as many types; all mean the same here
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            failure = f"video: env={env_cfg.name} cannot render here ({first})"
            if any(m in type(env.unwrapped).__module__ for m in ("mujoco", "safety_gymnasium")):
                failure = f"video: env={env_cfg.name} cannot render here (MUJOCO_GL={os.environ.get('MUJOCO_GL')}: {first}); {HEADLESS_GL}"
        if failure is not None:
            env.close()
            gc.collect()
    if failure is not None:
        raise VideoError(failure)
    if not isinstance(frame, np.ndarray) or frame.ndim != 3:
        env.close()
        raise VideoError(f"video: env={env_cfg.name} rendered {type(frame).__name__}, not an RGB frame")
    return env


def exact_fps(fps: float) -> int:
    """The power of two nearest ``fps``: moviepy counts a clip's frames as ``int(sum(n * [1 / fps]) * fps)``,
    which for most rates drops the last frame (moviepy issue #2507); with a power of two the sum is exact."""
    return 2 ** max(0, round(math.log2(fps)))


@contextlib.contextmanager
def _unraisable_ignored() -> Iterator[None]:
    """Drop the errors raised in ``__del__`` meanwhile (a failed renderer's tracebacks after the one-line error)."""
    hook, sys.unraisablehook = sys.unraisablehook, lambda _: None
    try:
        yield
    finally:
        sys.unraisablehook = hook


@torch.no_grad()
def record_video(
    agent: Agent,
    env_cfg: Any,
    video_dir: str | Path,
    episodes: int = 1,
    deterministic: bool = True,
    seed: int = 0,
    max_steps: int | None = None,
    algo: Any = None,
) -> list[VideoEpisode]:
    """``episodes`` episodes of ``agent`` on one rendering env of ``env_cfg`` (reset with ``seed`` once), one mp4
    each in ``video_dir``, cut at ``max_steps``; ``algo``'s ``observation_state`` (Sauté's budget) carried along."""
    from gymnasium.wrappers import RecordVideo

    env = make_render_env(env_cfg)
    env = RecordVideo(
        env,
        str(video_dir),
        episode_trigger=lambda i: i < episodes,
        name_prefix="policy",
        fps=exact_fps(env.metadata.get("render_fps", 30)),
    )
    policy = DeployedPolicy(agent, env.action_space, agent.num_costs)
    extra = None if algo is None else algo.observation_state(agent.cost_names)
    out: list[VideoEpisode] = []
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        obs, _ = env.reset(seed=seed)
        for i in range(episodes):
            state = step_cost = None
            ret, cost, steps = 0.0, 0.0, 0
            if extra is not None:
                extra.start()
            while True:
                obs_t = torch.as_tensor(np.asarray(obs, dtype=np.float32).reshape(1, -1))  # as GymVecEnv gives it
                if extra is not None:
                    obs_t = extra.observation(obs_t)
                action, state = policy.predict(obs_t, state, deterministic=deterministic, cost=step_cost)
                action = to_env(torch.as_tensor(action).view(1, -1), env.action_space)[0]  # as the vector env steps
                obs, reward, terminated, truncated, info = env.step(action)
                step_cost = np.asarray(info.get("cost", 0.0), dtype=np.float64).reshape(1, -1)  # [1, K]
                if extra is not None:
                    extra.observe(torch.as_tensor(step_cost, dtype=torch.float32))
                ret, cost, steps = ret + float(reward), cost + step_cost[0], steps + 1
                if terminated or truncated or (max_steps is not None and steps >= max_steps):
                    break
            episode_cost = float(cost[0]) if np.size(cost) == 1 else tuple(float(c) for c in cost)
            out.append(VideoEpisode(Path(video_dir) / f"policy-episode-{i}.mp4", steps + 1, ret, episode_cost))
            if i + 1 < episodes:
                obs, _ = env.reset()  # writes episode i's video
    env.close()  # writes the last one
    return out
