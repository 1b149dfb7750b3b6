"""``env=safe_nav`` against its physics bound: where ppo_lag training's time goes, per task, in one run.

    python experiments/speed/safe_nav_profile.py [--tasks PointGoal1 CarGoal1 PointButton1]
        [--seconds 8] [--train-steps 61440] [--threads 1 2] [--reference] [--quick]

For each task, in this order and back to back (so that the figures share the machine's load,
which is printed beside each):

1. **physics only**: ``NavWorlds.step`` (ten ``mj_step`` and one ``mj_forward`` per world; for the
   Button tasks, the gremlins moved before each physics step) on 16 worlds, random controls;
2. **env**: ``SafeNavVecEnv.step`` on 16 envs (physics, sensors, task logic, lidar, observation,
   automatic resets), random actions;
3. **training**: ``ppo_lag`` at its default options (``train.py algo=ppo_lag env=safe_nav
   env.task=...``: 16 envs, 128 steps per env and iteration, 8 minibatches, 10 epochs, checkpoint
   every 10 iterations) for ``--train-steps``, with ``eval_episodes=1`` (the final evaluation is
   not timed); once per ``--threads`` value (``env.threads``);
4. **physics only** again (the load moves: the bound is taken as the mean of 1 and 4).

Training's wall time (and the process's CPU time) is split by timers wrapped round the loop's
parts: env (of which physics), policy forward (``Agent.act``), the rest of the collector
(stacking the batch), the rollout check, GAE, the update (normalisers and the deployed policy's
bookkeeping included, GAE excluded), logging (rows, ``metrics.csv``, progress) and checkpoint.
"train s/s" is steps over the whole loop's wall time; "share" is that rate over the physics-only
rate; "1e7 CPU-min" is the loop's process CPU seconds per step times 1e7.

``--reference`` adds ``env=safety_gym``'s training rate on PointGoal1 (same options) and the
ratio (the issue's "bar 17"). Rates are rough on a shared machine: compare figures of one run.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import torch

from cmdp_rl import train
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.envs.safe_nav import world as world_module
from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import advantages, collector
from cmdp_rl.run import loop

PARTS = (
    "env",
    "  physics",
    "policy forward",
    "collector rest",
    "rollout check",
    "GAE",
    "update",
    "logging",
    "checkpoint",
)


def load() -> float:
    """The 1-minute load average (2 cores here: above 2, other jobs take a share of ours)."""
    return round(os.getloadavg()[0], 2)


class Clock:
    """Wall and process-CPU seconds per named part, summed over calls (nested parts are counted
    in their parents too: "physics" inside "env")."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = defaultdict(float)
        self.cpu: dict[str, float] = defaultdict(float)
        self.on = False  # only the training loop is timed (not construction, not the evaluation)

    @contextlib.contextmanager
    def part(self, name: str) -> Iterator[None]:
        if not self.on:
            yield
            return
        w, c = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall[name] += time.perf_counter() - w
            self.cpu[name] += time.process_time() - c

    def wrap(self, name: str, fn: Callable) -> Callable:
        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.part(name):
                return fn(*args, **kwargs)

        return timed


@contextlib.contextmanager
def patched(obj: Any, attr: str, value: Any) -> Iterator[None]:
    old = getattr(obj, attr)
    setattr(obj, attr, value)
    try:
        yield
    finally:
        setattr(obj, attr, old)


def _rates(step: Callable[[int], None], num_envs: int, seconds: float) -> tuple[float, float]:
    """(env steps per wall second, per CPU second of this process) of ``step(k)`` repeated for
    about ``seconds``."""
    steps, t0, c0 = 0, time.perf_counter(), time.process_time()
    while time.perf_counter() - t0 < seconds:
        step(steps)
        steps += 1
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return num_envs * steps / wall, num_envs * steps / cpu


def physics_rate(task: str, num_envs: int, seconds: float, threads: int = 1) -> tuple[float, float]:
    """``NavWorlds.step`` alone: (steps/s, steps per CPU-s)."""
    env = SafeNavVecEnv(task, num_envs, threads=threads)
    env.reset(seed=0)
    ctrl = np.random.default_rng(0).uniform(-1, 1, (256, num_envs, env.action_dim))
    try:
        return _rates(lambda k: env.worlds.step(ctrl[k % 256]), num_envs, seconds)
    finally:
        env.close()


def env_rate(task: str, num_envs: int, seconds: float, threads: int = 1) -> tuple[float, float]:
    """``SafeNavVecEnv.step`` (everything the env does): (steps/s, steps per CPU-s)."""
    env = SafeNavVecEnv(task, num_envs, threads=threads)
    env.reset(seed=0)
    actions = torch.rand(256, num_envs, env.action_dim, generator=torch.Generator().manual_seed(0)) * 2 - 1
    try:
        return _rates(lambda k: env.step(actions[k % 256]), num_envs, seconds)
    finally:
        env.close()


def profile_training(overrides: list[str]) -> dict[str, Any]:
    """Train with ``overrides`` under the part timers: steps, the loop's wall and CPU seconds, and
    each part's."""
    clock = Clock()
    cfg = compose_config(overrides)
    original_run = loop.TrainingLoop.run

    def run(self: loop.TrainingLoop, *args: Any) -> float:
        clock.on = True
        try:
            with clock.part("loop"):
                return original_run(self, *args)
        finally:
            clock.on = False

    def logged(fn: Callable) -> Callable:
        return clock.wrap("logging", fn)

    with contextlib.ExitStack() as stack:
        for obj, attr, name in (
            (SafeNavVecEnv, "step", "env"),
            (world_module.NavWorlds, "step", "  physics"),
            (Agent, "act", "policy forward"),
            (collector.Collector, "collect", "rollout"),
            (advantages.TwinGAE, "__call__", "GAE"),
            (loop, "check_rollout", "rollout check"),
            (loop.TrainingLoop, "update", "update"),
            (loop.TrainingLoop, "checkpoint", "checkpoint"),
        ):
            stack.enter_context(patched(obj, attr, clock.wrap(name, getattr(obj, attr))))
        stack.enter_context(patched(loop, "metrics_row", logged(loop.metrics_row)))
        stack.enter_context(patched(loop.TrainingLoop, "run", run))
        # logging's other half: the logger's and the progress bar's per-iteration calls
        from cmdp_rl.report.metrics import MetricsLogger
        from cmdp_rl.run.progress import Progress

        stack.enter_context(patched(MetricsLogger, "log", logged(MetricsLogger.log)))
        stack.enter_context(patched(Progress, "update", logged(Progress.update)))
        with tempfile.TemporaryDirectory() as tmp:
            train(cfg, Path(tmp) / "run", echo=lambda _: None)
    per_iter = cfg.rollout_steps * cfg.env.num_envs
    steps = per_iter * -(-cfg.total_steps // per_iter)
    w, c = clock.wall, clock.cpu
    parts = {name: (w[name], c[name]) for name in PARTS}
    parts["collector rest"] = (  # the collector's own work: collect minus the env and policy inside it
        w["rollout"] - w["env"] - w["policy forward"],
        c["rollout"] - c["env"] - c["policy forward"],
    )
    parts["update"] = (w["update"] - w["GAE"], c["update"] - c["GAE"])
    accounted = sum(v[0] for k, v in parts.items() if not k.startswith(" "))
    parts["other"] = (w["loop"] - accounted, c["loop"] - sum(v[1] for k, v in parts.items() if not k.startswith(" ")))
    return {"steps": steps, "wall_s": w["loop"], "cpu_s": c["loop"], "parts": parts}


def print_profile(task: str, threads: int, result: dict[str, Any], bound: tuple[float, float]) -> dict[str, Any]:
    """Print one training row and its parts; ``bound``: the physics-only (steps/s, steps per CPU-s)."""
    wall, cpu, steps = result["wall_s"], result["cpu_s"], result["steps"]
    rate, cpu_rate = steps / wall, steps / cpu
    physics = result["parts"]["  physics"]
    row = {
        "train_steps_per_s": rate,
        "train_steps_per_cpu_s": cpu_rate,
        "share_wall": rate / bound[0],
        "share_cpu": cpu_rate / bound[1],
        "physics_share_of_loop_cpu": physics[1] / cpu,
        "cpu_min_1e7": cpu / steps * 1e7 / 60,
    }
    print(
        f"{task:<12} train ppo_lag, env.threads={threads}: {steps:,} steps, {wall:.1f} s wall, {cpu:.1f} s CPU: "
        f"{rate:,.0f} steps/s ({row['share_wall']:.0%} of physics only), {cpu_rate:,.0f} per CPU-s "
        f"({row['share_cpu']:.0%}); physics {row['physics_share_of_loop_cpu']:.0%} of its CPU time; "
        f"1e7 steps = {row['cpu_min_1e7']:.1f} CPU-min   load {load()}",
        flush=True,
    )
    for name, (w, c) in result["parts"].items():
        print(f"{'':<14}{name:<16} {w:7.2f} s wall {w / wall:6.1%}   {c:7.2f} s CPU {c / cpu:6.1%}")
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=["PointGoal1", "CarGoal1", "PointButton1"])
    parser.add_argument("--seconds", type=float, default=8.0, help="per physics-only and env row")
    parser.add_argument("--train-steps", type=int, default=30 * 2048, help="per training row (30 iterations)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="env.threads values to train with")
    parser.add_argument("--reference", action="store_true", help="also env=safety_gym's training on PointGoal1")
    parser.add_argument("--quick", action="store_true", help="short rows (a smoke test; not for quoting)")
    parser.add_argument("--output", default="outputs/safe_nav_profile.json")
    args = parser.parse_args()
    torch.set_num_threads(1)  # the run's default (threads=1); train() sets it too
    seconds, train_steps = (1.0, 3 * 2048) if args.quick else (args.seconds, args.train_steps)
    n = 16
    out: dict[str, Any] = {"cores": os.cpu_count(), "load_start": os.getloadavg(), "tasks": {}}
    print(f"{os.cpu_count()} cores; load average at start {os.getloadavg()}", flush=True)
    for task in args.tasks:
        row: dict[str, Any] = {}

        def rates(name: str, wall_cpu: tuple[float, float]) -> tuple[float, float]:
            row[name] = wall_cpu
            print(f"{task:<12} {name:<34} {wall_cpu[0]:9,.0f} steps/s {wall_cpu[1]:9,.0f} per CPU-s   load {load()}")
            return wall_cpu

        before = rates("physics only (NavWorlds.step)", physics_rate(task, n, seconds))
        env = rates("env (SafeNavVecEnv.step)", env_rate(task, n, seconds))
        if 2 in args.threads:
            rates("env, env.threads=2", env_rate(task, n, seconds, threads=2))
        profiles = {}
        for threads in args.threads:
            overrides = ["algo=ppo_lag", "env=safe_nav", f"env.task={task}", f"env.threads={threads}"]
            profiles[threads] = profile_training([*overrides, f"total_steps={train_steps}", "eval_episodes=1"])
        after = rates("physics only, again", physics_rate(task, n, seconds))
        bound = ((before[0] + after[0]) / 2, (before[1] + after[1]) / 2)
        print(f"{task:<12} env = {env[0] / bound[0]:.0%} of physics only ({env[1] / bound[1]:.0%} per CPU-s)")
        for threads, result in profiles.items():
            row[f"threads={threads}"] = {**result, **print_profile(task, threads, result, bound)}
        if 1 in profiles and 2 in profiles:
            gain = profiles[1]["wall_s"] / profiles[2]["wall_s"]
            print(f"{task:<12} env.threads=2 trains {gain:.2f}x as fast as 1 (wall)")
        out["tasks"][task] = row
    if args.reference:
        rates = {}
        for env_args in (["env=safe_nav", "env.task=PointGoal1"], ["env=safety_gym", "env.task=SafetyPointGoal1-v0"]):
            result = profile_training(["algo=ppo_lag", *env_args, f"total_steps={train_steps // 6}", "eval_episodes=1"])
            rates[env_args[0]] = result["steps"] / result["wall_s"]
            print(f"PointGoal1   train ppo_lag, {env_args[0]:<15} {rates[env_args[0]]:9,.0f} steps/s   load {load()}")
        out["reference"] = rates
        print(f"PointGoal1   safe_nav / safety_gym training: {rates['env=safe_nav'] / rates['env=safety_gym']:.1f}x")
    print(f"load average at end {os.getloadavg()}")
    path = Path(args.output)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2, default=str))


__all__ = ["Clock", "env_rate", "physics_rate", "profile_training"]
