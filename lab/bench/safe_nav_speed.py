"""env=safe_nav against the reference (env=safety_gym): env steps/s and ppo_lag training steps/s,
all in one run so that the figures share the machine's load.

    python experiments/speed/safe_nav_speed.py [--tasks PointGoal1 CarGoal1] [--num-envs 1 16 64 256]
                                         [--reference-async 2 16] [--train-steps 32768] [--quick]

Rows (random uniform actions, torch threads = 1):

1. reference, plain loop: one Safety-Gymnasium env (``SafetyGymTask``, the real task via our
   compatibility layer), ``step`` and ``reset`` at each episode end, whole episodes (its resets
   recompile the MuJoCo world: their cost is part of its rate). A plain loop over N envs does the
   same work N times, so this is its rate at every N.
2. reference, gymnasium's ``AsyncVectorEnv`` (``env=safety_gym env.vector=async``, the batched
   env the collector drives), N worker processes, whole episodes. Each worker holds a MuJoCo model with 190 MB of
   textures, so N is kept to what memory allows (64 workers would need about 16 GB).
3. safe_nav at N = 1, 16, 64, 256 (``env.threads=1``, and 2 at N >= 16): ``SafeNavVecEnv.step``
   on pre-drawn actions, one whole episode per env at N <= 16, 250 steps per env above (resets, about
   a millisecond per env, measured apart and printed).
4. physics only, N = 16 and 64: ten ``mj_step`` and one ``mj_forward`` per env step, in our loop or
   through ``mujoco.rollout`` (its thread pool, 1 or 2 threads), to choose between them.
5. training: ``ppo_lag`` through ``train()`` on PointGoal1, 16 envs, ``env=safe_nav`` against
   ``env=safety_gym`` (sync; the trainer refuses ``env.vector=async`` on this commit), steps/s as metrics.csv's ``sps`` (median of iterations
   after the first).

The load average is printed before and after every row: on a shared machine the figures move
with it, so compare only figures from the same run.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from cmdp_rl import make_env, train
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv
from cmdp_rl.envs.safe_nav.spec import FRAMESKIP
from cmdp_rl.envs.safety_gym.env import SafetyGymEnvConfig, make_task


def load() -> float:
    return round(os.getloadavg()[0], 2)


def reference_loop(task: str, steps: int) -> float:
    env = make_task(f"Safety{task}-v0")
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, *env.action_space.shape))
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t0)


def timed_steps(env, steps_per_env: int) -> float:
    """Steps/s of ``steps_per_env`` uniform random batched steps of a reset VecEnv (closed after)."""
    actions = torch.rand(steps_per_env, env.num_envs, env.action_dim) * 2 - 1
    t0 = time.perf_counter()
    for a in actions:
        env.step(a)
    rate = env.num_envs * steps_per_env / (time.perf_counter() - t0)
    env.close()
    return rate


def reference_async(task: str, n: int, steps_per_env: int) -> float:
    env = make_env(SafetyGymEnvConfig(task=f"Safety{task}-v0", num_envs=n, vector="async"))
    env.reset(seed=0)  # worker start not timed
    return timed_steps(env, steps_per_env)


def safe_nav_rate(task: str, n: int, steps_per_env: int, threads: int) -> tuple[float, float]:
    """(steps/s, reset seconds per env)."""
    env = SafeNavVecEnv(task, n, threads=threads)
    t0 = time.perf_counter()
    env.reset(seed=0)
    reset_s = (time.perf_counter() - t0) / n
    return timed_steps(env, steps_per_env), reset_s


def physics_rates(task: str, n: int, steps: int) -> dict[str, float]:
    """Env steps/s of the physics alone: our loop, and mujoco.rollout (1 and 2 threads)."""
    import mujoco
    from mujoco import rollout

    env = SafeNavVecEnv(task, n)
    env.reset(seed=0)
    worlds = env.worlds
    ctrl = np.random.default_rng(0).uniform(-1, 1, (steps, n, env.action_dim))
    out = {}
    t0 = time.perf_counter()
    for c in ctrl:
        worlds.step(c)
    out["loop"] = n * steps / (time.perf_counter() - t0)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    models, datas = worlds.models, worlds.datas
    state = np.stack([np.empty(mujoco.mj_stateSize(models[0], spec)) for _ in range(n)])
    for i in range(n):
        mujoco.mj_getState(models[i], datas[i], state[i], spec)
    for threads in (1, 2):
        with rollout.Rollout(nthread=threads if threads > 1 else 0) as pool:
            scratch = [mujoco.MjData(models[0]) for _ in range(threads)] if threads > 1 else mujoco.MjData(models[0])
            s = state.copy()
            t0 = time.perf_counter()
            for c in ctrl:
                # FRAMESKIP steps with the same control, plus one for the sensors of the last state
                # (the rollout's step k records sensors of the state before it)
                controls = np.repeat(c[:, None, :], FRAMESKIP + 1, axis=1)
                states, _ = pool.rollout(models, scratch, s, controls, nstep=FRAMESKIP + 1)
                s = states[:, FRAMESKIP - 1]
            out[f"rollout_{threads}thread"] = n * steps / (time.perf_counter() - t0)
    return out


def train_rate(overrides: list[str], total_steps: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        cfg = compose_config([*overrides, "algo=ppo_lag", f"total_steps={total_steps}", "eval_episodes=1"])
        train(cfg, Path(tmp) / "run", echo=lambda _: None)
        with open(Path(tmp) / "run" / "metrics.csv") as f:
            sps = [float(row["sps"]) for row in csv.DictReader(f)]
    return statistics.median(sps[1:] or sps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="*", default=["PointGoal1", "CarGoal1"])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[1, 16, 64, 256])
    parser.add_argument("--reference-async", type=int, nargs="*", default=[2, 16])
    parser.add_argument("--no-physics", action="store_true", help="leave out the physics-only rows")
    parser.add_argument("--train-steps", type=int, default=16 * 1000 * 2, help="per training row (0: no training rows)")
    parser.add_argument("--quick", action="store_true", help="short rows (a smoke test; not for quoting)")
    parser.add_argument("--output", default="outputs/safe_nav_speed.json")
    args = parser.parse_args()
    torch.set_num_threads(1)
    episode = 100 if args.quick else 1000
    rows = []

    def row(name: str, task: str, n: int, sps: float, **extra) -> None:
        rows.append({"setup": name, "task": task, "num_envs": n, "steps_per_s": sps, "load": load(), **extra})
        print(f"{task:<10} {name:<46} N={n:<4} {sps:9,.0f} steps/s   load {rows[-1]['load']}", flush=True)

    print(f"{os.cpu_count()} cores; load average at start {os.getloadavg()}", flush=True)
    for task in args.tasks:
        row("reference, plain loop", task, 1, reference_loop(task, 2 * episode))
        for n in args.reference_async:
            row("reference, gymnasium AsyncVectorEnv", task, n, reference_async(task, n, episode))
        for n in args.num_envs:
            steps = episode if n <= 16 else episode // 4
            for threads in (1, 2) if n >= 16 else (1,):
                sps, reset_s = safe_nav_rate(task, n, steps, threads)
                row(f"safe_nav, {threads} thread(s)", task, n, sps, reset_ms_per_env=1e3 * reset_s)
        # (no physics-only rows for Button tasks: mujoco.rollout cannot move their gremlins'
        # mocap bodies between physics steps)
        for n in () if args.no_physics or "Button" in task else (16, 64):
            for how, sps in physics_rates(task, n, 50 if args.quick else 200).items():
                row(f"physics only: {how}", task, n, sps)
    train_steps = 16 * 64 * 2 if args.quick else args.train_steps
    if train_steps:
        base = ["env.num_envs=16", "env.task=PointGoal1"]
        row("train ppo_lag: safe_nav", "PointGoal1", 16, train_rate(["env=safe_nav", *base], train_steps))
        ref = ["env=safety_gym", "env.num_envs=16", "env.task=SafetyPointGoal1-v0"]
        row("train ppo_lag: safety_gym (sync)", "PointGoal1", 16, train_rate(ref, train_steps))
    # (env.vector=async is not trained here: the trainer's env-contract check refuses an
    # AsyncVectorEnv on this commit)
    print(f"load average at end {os.getloadavg()}")
    for task in args.tasks:
        best_ref = max(r["steps_per_s"] for r in rows if r["task"] == task and r["setup"].startswith("reference"))
        for r in rows:
            if r["task"] == task and r["setup"].startswith("safe_nav"):
                print(
                    f"{task} N={r['num_envs']:<4} {r['setup']:<22} {r['steps_per_s'] / best_ref:5.1f}x the reference's best"
                )
    trained = {r["setup"]: r["steps_per_s"] for r in rows if r["setup"].startswith("train")}
    if trained:
        ours = trained["train ppo_lag: safe_nav"]
        print(f"training: {ours / max(v for k, v in trained.items() if 'safety_gym' in k):.1f}x the reference's path")
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"cores": os.cpu_count(), "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
