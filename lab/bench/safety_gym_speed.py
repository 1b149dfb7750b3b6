"""Env steps per second on a Safety-Gymnasium task: the package's own loop against our collector,
with gymnasium's synchronous and asynchronous vector envs.

    python experiments/speed/safety_gym_speed.py [--task SafetyPointGoal1-v0] [--episodes 1] [--num-envs 2 8]

Rows (env transitions per second, random uniform actions, ``torch`` threads = 1):

1. Safety-Gymnasium's own loop: one env built from its registered entry point, ``step`` (six
   values) and ``reset`` when an episode ends. The package's rate on this machine.
2. Our ``SafetyGymTask`` (the five-value adapter, cost to ``info``), one env, the same loop.
3. ``env=safety_gym`` with ``env.vector=sync``: N envs in gymnasium's ``SyncVectorEnv`` in this
   process, driven by our ``Collector`` (the training path, policy replaced by random actions).
4. The same with ``env.vector=async``: one worker process per env (gymnasium's ``AsyncVectorEnv``).

Every row runs whole episodes (``--episodes`` per env, 1000 steps each for the navigation tasks),
so each pays its share of resets, which rebuild and recompile the MuJoCo world (a fifth of the time,
by /work/shared/notes/safety-gymnasium-facts.md). The machine's load (``os.getloadavg``) is
printed before and after: on a shared machine the figures move with it.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from cmdp_rl import Collector, make_env
from cmdp_rl.envs.safety_gym.env import SafetyGymEnvConfig, make_task
from cmdp_rl.envs.safety_gym.tasks import TASKS
from cmdp_rl.rollout import keys


def package_env(task: str):
    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    from cmdp_rl.envs.safety_gym.compat import import_safety_gymnasium

    import_safety_gymnasium()
    spec = gym.spec(task)
    return load_env_creator(spec.entry_point)(**spec.kwargs)


def single_loop(env, steps: int, six: bool) -> float:
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(env.action_space.low, env.action_space.high, (steps, *env.action_space.shape))
    actions = actions.astype(env.action_space.dtype)
    t0 = time.perf_counter()
    for a in actions:
        out = env.step(a)
        terminated, truncated = (out[3], out[4]) if six else (out[2], out[3])
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t0)


class RandomActions:
    """The collector's side of an agent (``initial_state``, ``act``) drawing uniform random actions
    in the env's box: the env path alone, no network."""

    in_keys = [keys.OBS]

    def __init__(self, low: torch.Tensor, high: torch.Tensor, seed: int = 0) -> None:
        self.low, self.high = low, high
        self.gen = torch.Generator().manual_seed(seed)

    def initial_state(self, num_envs: int, device: torch.device | str = "cpu") -> dict:
        return {}

    def act(self, d, deterministic: bool = False) -> dict:
        n = d[keys.OBS].shape[0]
        return {keys.ACTION: self.low + (self.high - self.low) * torch.rand(n, self.low.shape[0], generator=self.gen)}


def collector_rate(task: str, n: int, steps_per_env: int, vector: str, safe_nav: bool = False) -> float:
    """Steps/s of our collector on ``task`` with random actions; ``safe_nav``: on ``env=safe_nav``'s
    batched twin of the task instead (``vector`` is then not read)."""
    if safe_nav:
        from cmdp_rl.envs.safe_nav.env import SafeNavEnvConfig

        env = make_env(SafeNavEnvConfig(task=task.removeprefix("Safety").removesuffix("-v0"), num_envs=n))
    else:
        env = make_env(SafetyGymEnvConfig(task=task, num_envs=n, vector=vector))
    collector = Collector(
        env, RandomActions(env.action_low, env.action_high), rollout_steps=steps_per_env, seed=0
    )  # reset (and worker start) not timed
    t0 = time.perf_counter()
    collector.collect()
    rate = collector.total_steps / (time.perf_counter() - t0)
    env.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="SafetyPointGoal1-v0")
    parser.add_argument("--episodes", type=int, default=1, help="whole episodes per env in every row")
    parser.add_argument("--num-envs", type=int, nargs="+", default=[2, 8])
    parser.add_argument("--output", default="outputs/safety_gym_speed.json")
    args = parser.parse_args()
    torch.set_num_threads(1)
    steps = TASKS[args.task] * args.episodes
    load_before = os.getloadavg()
    rows = [
        (
            "Safety-Gymnasium's own loop, 1 env (six-value step)",
            1,
            single_loop(package_env(args.task), steps, six=True),
        ),
        (
            "cmdp_rl SafetyGymTask, 1 env (five-value step, cost in info)",
            1,
            single_loop(make_task(args.task), steps, six=False),
        ),
    ]
    for n in args.num_envs:
        for vector in ("sync", "async"):
            rows.append(
                (f"cmdp_rl Collector, env.vector={vector}, {n} envs", n, collector_rate(args.task, n, steps, vector))
            )
    load_after = os.getloadavg()
    width = max(len(r[0]) for r in rows)
    print(
        f"{args.task}, {steps} steps per env, {os.cpu_count()} cores; load average (1, 5, 15 min) "
        f"before {tuple(round(x, 2) for x in load_before)}, after {tuple(round(x, 2) for x in load_after)}"
    )
    print(f"{'setup':<{width}} | steps/s")
    print(f"{'-' * width}-|--------")
    for name, _, sps in rows:
        print(f"{name:<{width}} | {sps:7,.0f}")
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "task": args.task,
                "steps_per_env": steps,
                "cores": os.cpu_count(),
                "load_before": load_before,
                "load_after": load_after,
                "rows": [{"setup": name, "num_envs": n, "steps_per_s": sps} for name, n, sps in rows],
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
