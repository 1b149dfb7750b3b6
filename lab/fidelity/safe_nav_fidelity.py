"""env=safe_nav against the real Safety-Gymnasium tasks, step for step, over whole episodes.

    python experiments/fidelity/safe_nav_fidelity.py [--tasks PointGoal0 ... CarGoal2] [--num-envs 2]
                                            [--steps 2100] [--seed 11]

For each task: ``--num-envs`` reference envs (``SafetyGymTask``: Safety-Gymnasium 1.0.0's own task
via our compatibility layer, same mujoco) reset with seeds ``seed + i`` and one ``SafeNavVecEnv``
reset with ``seed`` (so each env draws the reference's layout), then the same actions for
``--steps`` steps (2100: two whole episodes and the automatic resets between them). The actions
mostly steer each robot to its goal (with 30% uniform noise), so that goals are reached and hazards
and vases hit (Circle tasks: round the circle of radius 1.5, so that the sigwalls are crossed;
Button tasks: to the goal button, and every other 80 steps to a wrong one; Push tasks: round the
box to behind it, then through it towards the goal). Printed per task: the largest difference of any observation entry (float64), of any
reward, the number of steps whose cost, terminated or truncated differ, whether the MuJoCo states
(qpos, qvel, sensors) were equal bit for bit at every step, and what happened (goals, cost steps,
episode ends). The JSON has the same figures.

``--train`` also trains ppo_lag with the same config and seed on ``env=safe_nav`` and on
``env=safety_gym`` (PointGoal1, 2 envs, 4 iterations of 200 steps, 200-step episodes) and reports
whether the two runs logged the same metrics.csv rows (wall-clock columns aside) and the same
evaluation. (Not a CI test: the reference's side takes about 30 s, most of it compiling worlds.)
"""

from __future__ import annotations

import argparse
import csv
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from cmdp_rl.envs.safe_nav.env import TASKS, SafeNavVecEnv
from cmdp_rl.envs.safety_gym.env import make_task


def target(env: SafeNavVecEnv, pos: np.ndarray) -> np.ndarray:
    """The goal; on Circle tasks a point ahead on the circle of radius 1.5 (past the sigwalls); on
    Button tasks a wrong button every other 80 steps (so that wrong buttons are pressed too); on
    Push tasks round the box and through it."""
    if env.spec.family == "Circle":
        phi = np.arctan2(pos[:, 1], pos[:, 0]) + 0.6
        return 1.5 * np.c_[np.cos(phi), np.sin(phi)]
    if env.spec.family == "Push":  # round the box to behind it (seen from the goal), then through it
        box = env.worlds.gather(range(env.num_envs))["xpos"][:, env.worlds.push_box, :2]
        ahead = env.logic.goal - box
        ahead /= np.linalg.norm(ahead, axis=-1, keepdims=True) + 1e-9
        rel = pos[:, :2] - box
        normal = np.c_[-ahead[:, 1], ahead[:, 0]]
        side = normal * np.sign(np.sum(rel * normal, axis=-1) + 1e-9)[:, None]
        behind, past = box - 0.5 * ahead, np.sum(rel * ahead, axis=-1) > -0.25
        ready = (np.linalg.norm(pos[:, :2] - behind, axis=-1) < 0.3) & ~past
        around = box + 0.6 * side - 0.3 * ahead
        return np.where(ready[:, None], box + 0.2 * ahead, np.where(past[:, None], around, behind))
    if env.spec.family == "Button":
        logic = env.logic
        pick = (logic.goal_button + (env.steps // 80) % 2) % env.spec.buttons
        return logic.buttons[np.arange(env.num_envs), pick]
    return env.logic.goal


def steer(env: SafeNavVecEnv, rng: np.random.Generator) -> np.ndarray:
    """Actions that mostly steer each robot to its :func:`target` (so that goals are reached and
    hazards crossed on the way), with some noise; also tests/test_safe_nav.py's actions."""
    world = env.worlds.gather(range(env.num_envs))
    pos, mat = world["agent_pos"], world["agent_mat"]
    ego = np.einsum("ni,nij->nj", np.c_[target(env, pos) - pos[:, :2], -pos[:, 2:]], mat)
    if env.spec.robot == "point":
        angle = np.arctan2(ego[:, 1], ego[:, 0])
        act = np.c_[np.where(np.abs(angle) < 0.6, 1.0, 0.1), np.clip(2 * angle, -1, 1)]
    else:
        angle = np.arctan2(-ego[:, 0], -ego[:, 1])
        forward, turn = np.where(np.abs(angle) < 0.6, 1.0, 0.0), np.clip(2 * angle, -1, 1)
        act = np.c_[forward - turn, forward + turn]
    return np.clip(0.7 * act + 0.3 * rng.uniform(-1, 1, act.shape), -1, 1).astype(np.float32)


def compare(task: str, n: int, steps: int, seed: int) -> dict:
    refs = [make_task(f"Safety{task}-v0") for _ in range(n)]
    env = SafeNavVecEnv(task, n)
    env.reset(seed=seed)
    for i, r in enumerate(refs):
        r.reset(seed=seed + i)
    rng = np.random.default_rng(0)
    out = {
        "task": task,
        "num_envs": n,
        "steps": steps,
        "obs_max_abs_diff": 0.0,
        "reward_max_abs_diff": 0.0,
        "cost_mismatches": 0,
        "end_mismatches": 0,
        "physics_bit_equal": True,
        "goals": 0,
        "cost_steps": 0,
        "episode_ends": 0,
    }
    t0 = time.perf_counter()
    for _ in range(steps):
        action = steer(env, rng)
        res = [r.step(a) for r, a in zip(refs, action)]
        s = env.step(torch.from_numpy(action))
        for i, r in enumerate(refs):  # compare the worlds before the reference resets its own
            d, rd = env.worlds.datas[i], r.inner.task.data
            if not (
                np.array_equal(d.qpos, rd.qpos)
                and np.array_equal(d.qvel, rd.qvel)
                and np.array_equal(d.sensordata, rd.sensordata)
            ) and not (res[i][2] or res[i][3]):
                out["physics_bit_equal"] = False
        obs = np.stack([x[0] for x in res])
        out["obs_max_abs_diff"] = max(out["obs_max_abs_diff"], float(np.abs(env.last["next_obs"] - obs).max()))
        out["reward_max_abs_diff"] = max(
            out["reward_max_abs_diff"], float(np.abs(env.last["reward"] - [x[1] for x in res]).max())
        )
        cost = np.array([x[4]["cost"] for x in res])
        out["cost_mismatches"] += int(np.any(s.cost[:, 0].numpy() != cost))
        ends = np.c_[[x[2] for x in res], [x[3] for x in res]]
        out["end_mismatches"] += int(np.any(np.c_[s.terminated.numpy(), s.truncated.numpy()] != ends))
        out["goals"] += sum(x[4].get("goal_met", False) for x in res)
        out["cost_steps"] += int(cost.sum())
        for r, x in zip(refs, res):
            if x[2] or x[3]:
                out["episode_ends"] += 1
                r.reset()
    out["seconds"] = time.perf_counter() - t0
    return out


def same_training() -> bool:
    from cmdp_rl import train
    from cmdp_rl.config.run_config import compose_config

    common = [
        "env.num_envs=2",
        "env.max_steps=200",
        "rollout_steps=100",
        "total_steps=800",
        "eval_episodes=2",
        "algo=ppo_lag",
        "seed=3",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        runs = {
            "nav": ["env=safe_nav", "env.task=PointGoal1"],
            "gym": ["env=safety_gym", "env.task=SafetyPointGoal1-v0"],
        }
        logged = {}
        for name, env in runs.items():
            train(compose_config([*env, *common]), Path(tmp) / name, echo=lambda _: None)
            with open(Path(tmp) / name / "metrics.csv") as f:
                rows = [{k: v for k, v in r.items() if k not in ("sps", "time_s")} for r in csv.DictReader(f)]
            evaluation = json.loads((Path(tmp) / name / "eval.json").read_text())
            evaluation.pop("train_time_s")
            logged[name] = (rows, evaluation)
    same = logged["nav"] == logged["gym"]
    print(
        f"ppo_lag, same config and seed, {len(logged['nav'][0])} iterations: "
        f"{'the same' if same else 'DIFFERENT'} metrics.csv rows and evaluation on safe_nav and safety_gym"
    )
    return same


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--num-envs", type=int, default=2)
    parser.add_argument("--steps", type=int, default=2100)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--output", default="outputs/safe_nav_fidelity.json")
    parser.add_argument("--train", action="store_true", help="also compare two ppo_lag runs")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.train:
        same_training()
    rows = [compare(task, args.num_envs, args.steps, args.seed) for task in args.tasks]
    print(
        "| task | env steps | max abs obs diff | max abs reward diff | cost / end mismatches | physics bit-equal | goals | cost steps | episode ends |"
    )
    print("|---|--:|--:|--:|--:|:-:|--:|--:|--:|")
    for r in rows:
        print(
            f"| {r['task']} | {r['num_envs'] * r['steps']} | {r['obs_max_abs_diff']:.1e} | {r['reward_max_abs_diff']:.1e} "
            f"| {r['cost_mismatches']} / {r['end_mismatches']} | {'yes' if r['physics_bit_equal'] else 'NO'} "
            f"| {r['goals']} | {r['cost_steps']} | {r['episode_ends']} |"
        )
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
