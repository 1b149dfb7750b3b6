"""How env=safety_gym on our stack relates to Safety-Gymnasium on the stack it was released for.

    python experiments/fidelity/safety_gym_fidelity.py [--python python3.10] [--episodes 2] [--tasks ...]

A one-off measurement, not a test (it builds a second virtual environment, ``.venv-sg-pinned``,
with pip downloads). Steps:

1. The pinned original: a virtual environment on Python 3.10 (Safety-Gymnasium 1.0.0's own
   Pythons stop at 3.10; 3.11 rejects its dataclasses) with ``safety-gymnasium==1.0.0`` installed
   with its own dependencies (gymnasium 0.28.1, mujoco 2.3.3, pygame 2.1.0, gymnasium-robotics 1.2.2)
   and ``numpy<2`` (mujoco 2.3.3's wheels are built against numpy 1). Envs are built with
   ``safety_gymnasium.make``, the package's own way.
2. Ours: the same tasks through ``cmdp_rl.envs.safety_gym.env.make_task`` in this interpreter
   (gymnasium 1.x, mujoco 3+/4, numpy 2, the compatibility layer).
3. Both sides reset each task with the same seed, then apply the same actions (uniform in the
   action box, drawn here once and handed to both), resetting (without a seed) whenever an episode
   ends, for ``--episodes`` episodes' worth of steps. Each side records observations, rewards,
   costs and episode ends; this script compares them: the first step where anything differs, the
   largest differences before and after that, costs and episode ends that disagree, and per-episode
   sums.

The time each phase takes (venv creation and downloads included) is printed. Results go to
``outputs/safety_gym_fidelity.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
PINNED = ["safety-gymnasium==1.0.0", "gymnasium==0.28.1", "mujoco==2.3.3", "numpy<2"]
DEFAULT_TASKS = [
    "SafetyPointGoal1-v0",
    "SafetyCarGoal1-v0",
    "SafetyPointButton1-v0",
    "SafetyPointPush1-v0",
    "SafetyPointCircle1-v0",
    "SafetyDoggoGoal1-v0",
    "SafetyHalfCheetahVelocity-v1",
    "SafetyAntVelocity-v1",
]


# -- one side's rollout: runs in both interpreters, so it imports nothing of cmdp_rl ---------------


def rollout(make, task: str, seed: int, actions: np.ndarray, six: bool) -> dict[str, np.ndarray]:
    env = make(task)
    obs, _ = env.reset(seed=seed)
    out = {"obs": [], "reward": [], "cost": [], "terminated": [], "truncated": [], "reset_obs": [np.asarray(obs)]}
    for a in actions:
        step = env.step(a.astype(env.action_space.dtype))
        if six:
            obs, reward, cost, terminated, truncated, _ = step
        else:
            obs, reward, terminated, truncated, info = step
            cost = info["cost"]
        out["obs"].append(np.asarray(obs, dtype=np.float64))
        out["reward"].append(float(reward))
        out["cost"].append(float(cost))
        out["terminated"].append(bool(terminated))
        out["truncated"].append(bool(truncated))
        if terminated or truncated:
            obs, _ = env.reset()
            out["reset_obs"].append(np.asarray(obs))
    env.close()
    return {k: np.asarray(v) for k, v in out.items()}


def pinned_worker(request: str, result: str) -> None:
    """Runs in the pinned venv: ``safety_gymnasium.make`` as the package intends."""
    import gymnasium
    import mujoco
    import safety_gymnasium

    req = np.load(request, allow_pickle=True)
    arrays, timings = {}, {}
    for task, seed in zip(req["tasks"], req["seeds"]):
        t0 = time.perf_counter()
        data = rollout(lambda t: safety_gymnasium.make(t), str(task), int(seed), req[f"actions/{task}"], six=True)
        timings[str(task)] = len(data["reward"]) / (time.perf_counter() - t0)
        arrays.update({f"{task}/{k}": v for k, v in data.items()})
    versions = {
        "python": sys.version.split()[0],
        "gymnasium": gymnasium.__version__,
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "safety_gymnasium": safety_gymnasium.__version__,
    }
    np.savez(result, meta=json.dumps({"versions": versions, "steps_per_s": timings}), **arrays)


# -- the driver -----------------------------------------------------------------------------------


def find_python(name: str) -> str:
    found = shutil.which(name)
    if found and subprocess.run([found, "-V"], capture_output=True).returncode == 0:
        return found
    pyenv = Path.home() / ".pyenv" / "versions"
    for version in sorted(pyenv.glob(name.removeprefix("python") + "*"), reverse=True):
        candidate = version / "bin" / name
        if candidate.exists():
            return str(candidate)
    raise SystemExit(f"no {name} found (pass --python)")


def make_pinned_venv(python: str, venv: Path) -> dict:
    t0 = time.perf_counter()
    if not (venv / ".ready").exists():
        subprocess.run([python, "-m", "venv", "--clear", str(venv)], check=True)
        pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q"]
        subprocess.run([*pip, "--upgrade", "pip"], check=True)
        subprocess.run([*pip, *PINNED], check=True)
        (venv / ".ready").touch()
    freeze = subprocess.run(
        [str(venv / "bin" / "python"), "-m", "pip", "freeze"], capture_output=True, text=True
    ).stdout
    return {"seconds": time.perf_counter() - t0, "freeze": freeze.split()}


def ours(tasks, seeds, actions) -> tuple[dict, dict, dict]:
    import gymnasium
    import mujoco

    from cmdp_rl.envs.safety_gym.env import make_task

    arrays, timings = {}, {}
    for task, seed in zip(tasks, seeds):
        t0 = time.perf_counter()
        data = rollout(make_task, task, seed, actions[task], six=False)
        timings[task] = len(data["reward"]) / (time.perf_counter() - t0)
        arrays.update({f"{task}/{k}": v for k, v in data.items()})
    versions = {
        "python": sys.version.split()[0],
        "gymnasium": gymnasium.__version__,
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
    }
    return arrays, versions, timings


def episode_sums(values: np.ndarray, ends: np.ndarray) -> list[float]:
    sums, start = [], 0
    for i in np.flatnonzero(ends):
        sums.append(float(values[start : i + 1].sum()))
        start = i + 1
    return sums


def compare(task: str, a: dict, b: dict) -> dict:
    """``a``: the pinned original, ``b``: ours."""
    get = lambda d, k: d[f"{task}/{k}"]  # noqa: E731
    obs_diff = np.abs(get(a, "obs") - get(b, "obs")).max(axis=1)
    rew_diff = np.abs(get(a, "reward") - get(b, "reward"))
    cost_differs = get(a, "cost") != get(b, "cost")
    ends_a = get(a, "terminated") | get(a, "truncated")
    ends_b = get(b, "terminated") | get(b, "truncated")
    any_diff = (obs_diff > 0) | (rew_diff > 0) | cost_differs | (ends_a != ends_b)
    first = int(np.argmax(any_diff)) if any_diff.any() else None
    first_big = np.flatnonzero(obs_diff > 1e-6)
    steps = len(obs_diff)

    def window(x, lo, hi):
        part = x[lo:hi]
        return None if len(part) == 0 else {"max": float(part.max()), "median": float(np.median(part))}

    starts_a, starts_b = get(a, "reset_obs"), get(b, "reset_obs")
    k = min(len(starts_a), len(starts_b))
    return {
        "steps": steps,
        "identical": first is None,
        "first_step_differing": first,  # 0-based index of the step
        "first_step_obs_diff_over_1e-6": int(first_big[0]) if len(first_big) else None,
        "obs_max_abs_diff": {
            "steps_1_10": window(obs_diff, 0, 10),
            "steps_1_100": window(obs_diff, 0, 100),
            "all": window(obs_diff, 0, steps),
        },
        "reward_max_abs_diff": {"steps_1_100": window(rew_diff, 0, 100), "all": window(rew_diff, 0, steps)},
        "cost_steps": {
            "pinned": int((get(a, "cost") > 0).sum()),
            "ours": int((get(b, "cost") > 0).sum()),
            "disagreeing": int(cost_differs.sum()),
        },
        "episode_ends": {"pinned": np.flatnonzero(ends_a).tolist(), "ours": np.flatnonzero(ends_b).tolist()},
        "episode_start_obs_max_abs_diff": [float(np.abs(starts_a[i] - starts_b[i]).max()) for i in range(k)],
        "episode_return": {
            "pinned": episode_sums(get(a, "reward"), ends_a),
            "ours": episode_sums(get(b, "reward"), ends_b),
        },
        "episode_cost": {"pinned": episode_sums(get(a, "cost"), ends_a), "ours": episode_sums(get(b, "cost"), ends_b)},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--python", default="python3.10", help="interpreter for the pinned venv")
    parser.add_argument("--venv", default=str(ROOT / ".venv-sg-pinned"))
    parser.add_argument("--tasks", nargs="+", default=DEFAULT_TASKS)
    parser.add_argument("--episodes", type=int, default=2, help="episodes' worth of steps per task")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--output", default=str(ROOT / "outputs" / "safety_gym_fidelity.json"))
    parser.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        pinned_worker(*args.worker)
        return

    from cmdp_rl.envs.safety_gym.env import make_task
    from cmdp_rl.envs.safety_gym.tasks import TASKS

    setup = make_pinned_venv(find_python(args.python), Path(args.venv))
    print(f"pinned venv ready in {setup['seconds']:.0f} s")
    seeds = [args.seed + i for i in range(len(args.tasks))]
    rng = np.random.default_rng(args.seed)
    actions = {}
    for task in args.tasks:
        space = make_task(task).action_space
        actions[task] = rng.uniform(space.low, space.high, (TASKS[task] * args.episodes, *space.shape))
    with tempfile.TemporaryDirectory() as tmp:
        request, result = os.path.join(tmp, "request.npz"), os.path.join(tmp, "result.npz")
        np.savez(
            request,
            tasks=np.array(args.tasks),
            seeds=np.array(seeds),
            **{f"actions/{t}": a for t, a in actions.items()},
        )
        t0 = time.perf_counter()
        subprocess.run(
            [str(Path(args.venv) / "bin" / "python"), __file__, "--worker", request, result], check=True, cwd=tmp
        )  # not the repository root: the pinned side must not see cmdp_rl
        pinned_seconds = time.perf_counter() - t0
        with np.load(result, allow_pickle=False) as f:
            pinned = {k: f[k] for k in f.files}
    meta = json.loads(str(pinned.pop("meta")))
    t0 = time.perf_counter()
    mine, versions, timings = ours(args.tasks, seeds, actions)
    ours_seconds = time.perf_counter() - t0
    report = {
        "pinned": {
            **meta,
            "seconds": pinned_seconds,
            "venv_setup_seconds": setup["seconds"],
            "freeze": setup["freeze"],
        },
        "ours": {"versions": versions, "steps_per_s": timings, "seconds": ours_seconds},
        "seed": args.seed,
        "episodes": args.episodes,
        "tasks": {task: compare(task, pinned, mine) for task in args.tasks},
    }
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1))
    print(f"pinned {meta['versions']}, ours {versions}; rollouts {pinned_seconds:.0f} s / {ours_seconds:.0f} s")
    print(
        f"{'task':<30} {'first diff':>10} {'obs diff 1-100':>15} {'obs diff all':>13} {'rew diff all':>13} "
        f"{'cost steps p/o':>15} {'ends same':>9}"
    )
    for task, r in report["tasks"].items():
        o100, oall, rall = (
            r["obs_max_abs_diff"]["steps_1_100"],
            r["obs_max_abs_diff"]["all"],
            r["reward_max_abs_diff"]["all"],
        )
        print(
            f"{task:<30} {str(r['first_step_differing']):>10} {o100['max']:>15.2e} {oall['max']:>13.2e} "
            f"{rall['max']:>13.2e} {r['cost_steps']['pinned']:>7}/{r['cost_steps']['ours']:<7} "
            f"{str(r['episode_ends']['pinned'] == r['episode_ends']['ours']):>9}"
        )
    print(f"written to {out}")


if __name__ == "__main__":
    main()
