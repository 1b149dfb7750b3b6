"""Steps per second on a velocity task: gymnasium's raw stepping against our collection and training.

    python experiments/speed/velocity_speed.py [--task HalfCheetah] [--steps 20000] [--num-envs 8]

Rows (env transitions per second, one process, ``threads=1``):

1. ``gymnasium.make("<task>-v5")``, one env, random actions: the simulator's own rate.
2. The same task with its velocity cost, 8 envs in gymnasium's ``SyncVectorEnv`` (SAME_STEP
   autoreset), random actions: what our env layer steps.
3. Our ``GymVecEnv`` + ``Collector`` + the MLP actor (sampling, no learning): rollout cost.
4. ``cmdp_rl.train`` with the velocity benchmark's settings (collect + GAE + 10 PPO epochs +
   logging): end-to-end training rate.

On a shared machine the figures move with the other load; run it twice and quote both.
"""

from __future__ import annotations

import argparse
import csv
import tempfile
import time

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from cmdp_rl import Collector, load_config, make_agent, make_env, train
from cmdp_rl.envs.velocity import make_velocity_env
from cmdp_rl.rollout.normalization import make_normalizers


def raw_single(task: str, steps: int) -> float:
    env = gym.make(f"{task}-v5")
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, *env.action_space.shape)).astype(np.float32)
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t0)


def raw_vector(task: str, steps: int, n: int) -> float:
    envs = SyncVectorEnv([lambda: make_velocity_env(task) for _ in range(n)], autoreset_mode=AutoresetMode.SAME_STEP)
    envs.reset(seed=0)
    shape = envs.single_action_space.shape
    actions = np.random.default_rng(0).uniform(-1, 1, (steps // n, n, *shape)).astype(np.float32)
    t0 = time.perf_counter()
    for a in actions:
        envs.step(a)
    return (steps // n) * n / (time.perf_counter() - t0)


def collection(task: str, steps: int, n: int) -> float:
    cfg = load_config({"env": {"name": "velocity", "task": task, "num_envs": n}, "normalize": {"obs": True}})
    env = make_env(cfg.env)
    ac = make_agent(cfg.policy, env, make_normalizers(cfg, env))
    collector = Collector(env, ac, rollout_steps=max(1, steps // n), seed=0)
    t0 = time.perf_counter()
    collector.collect()
    return collector.total_steps / (time.perf_counter() - t0)


def training(task: str, iterations: int, n: int) -> tuple[float, float]:
    """Mean steps/s of the iterations after the first, and of the whole run (with evaluation)."""
    rollout = 256
    cfg = load_config(
        {
            "env": {"name": "velocity", "task": task, "num_envs": n},
            "normalize": {"obs": True},
            "algo": {"name": "ppo_lag", "cost_limit": 25.0},
            "rollout_steps": rollout,
            "total_steps": iterations * rollout * n,
            "eval_episodes": 1,
            "log_interval": 10**6,
        }
    )
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        train(cfg, out, echo=lambda _: None)
        wall = time.perf_counter() - t0
        rows = list(csv.DictReader(open(f"{out}/metrics.csv")))
    sps = [float(r["sps"]) for r in rows[1:]]
    return float(np.mean(sps)), cfg.total_steps / wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="HalfCheetah")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=6)
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = [
        (f"gymnasium {args.task}-v5, 1 env, random actions", raw_single(args.task, args.steps)),
        (
            f"gymnasium SyncVectorEnv x{args.num_envs} + velocity cost, random actions",
            raw_vector(args.task, args.steps, args.num_envs),
        ),
        (
            f"cmdp_rl GymVecEnv x{args.num_envs} + Collector + MLP actor (no learning)",
            collection(args.task, args.steps, args.num_envs),
        ),
    ]
    per_iter, overall = training(args.task, args.iterations, args.num_envs)
    rows.append((f"cmdp_rl train, ppo_lag, {args.num_envs} envs x 256 steps, 10 epochs (per iteration)", per_iter))
    rows.append(
        (f"cmdp_rl train, the same, whole run incl. set-up and 1 eval episode ({args.iterations} iterations)", overall)
    )
    width = max(len(r[0]) for r in rows)
    print(f"{'setup':<{width}} | steps/s")
    print(f"{'-' * width}-|--------")
    for name, sps in rows:
        print(f"{name:<{width}} | {sps:7,.0f}")


if __name__ == "__main__":
    main()
