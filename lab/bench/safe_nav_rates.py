"""How fast ``env=safe_nav`` runs on each physics backend: env steps/s and training steps/s against N.

Used by experiments/speed/safe_nav_warp_speed.py (docs/safe_nav.md, "MuJoCo Warp"). Rates are
measured after a warm-up step (Warp compiles its kernels and records its graph on first use; the
warm-up's seconds are reported apart), on uniform random actions drawn on the env's device.
"""

from __future__ import annotations

import csv
import os
import statistics
import tempfile
import time
from pathlib import Path

import torch

from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv


def load() -> float:
    """The 1-minute load average (figures from a shared machine are read beside it)."""
    return round(os.getloadavg()[0], 2)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def env_rate(task: str, physics: str, num_envs: int, steps: int, device: str = "cpu") -> dict:
    """Env steps/s of ``steps`` batched steps (resets included) of ``num_envs`` envs after one
    warm-up step; also the seconds of construction plus first reset and step."""
    dev = torch.device(device)
    t0 = time.perf_counter()
    env = SafeNavVecEnv(task, num_envs, device=dev, physics=physics)
    env.reset(seed=0)
    gen = torch.Generator(device=dev).manual_seed(0)
    env.step(torch.rand(num_envs, env.action_dim, generator=gen, device=dev) * 2 - 1)
    _sync(dev)
    warmup = time.perf_counter() - t0
    actions = torch.rand(steps, num_envs, env.action_dim, generator=gen, device=dev) * 2 - 1
    t0 = time.perf_counter()
    for a in actions:
        env.step(a)
    _sync(dev)
    seconds = time.perf_counter() - t0
    env.close()
    return {"steps_per_s": num_envs * steps / seconds, "warmup_s": warmup}


def train_rate(task: str, physics: str, num_envs: int, total_steps: int, device: str = "cpu", extra=()) -> float:
    """ppo_lag training steps/s through ``train()``: the median of metrics.csv's ``sps`` over the
    iterations after the first (which pays for compiling and recording)."""
    from cmdp_rl import train
    from cmdp_rl.config.run_config import compose_config

    overrides = [
        "env=safe_nav",
        f"env.task={task}",
        f"env.physics={physics}",
        f"env.num_envs={num_envs}",
        "algo=ppo_lag",
        f"total_steps={total_steps}",
        "eval_episodes=1",
        f"device={device}",
        *extra,
    ]
    with tempfile.TemporaryDirectory() as tmp:
        train(compose_config(overrides), Path(tmp) / "run", echo=lambda _: None)
        with open(Path(tmp) / "run" / "metrics.csv") as f:
            sps = [float(row["sps"]) for row in csv.DictReader(f)]
    return statistics.median(sps[1:] or sps)


__all__ = ["env_rate", "load", "train_rate"]
