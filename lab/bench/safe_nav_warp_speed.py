"""env=safe_nav on MuJoCo Warp against MuJoCo: env steps/s and ppo_lag training steps/s against N,
both physics in one run (so that the figures share the machine's load).

    python experiments/speed/safe_nav_warp_speed.py [--device cpu|cuda] [--task PointGoal1]
        [--num-envs 1 16 256 4096 16384] [--steps 200] [--train-num-envs 16 4096]
        [--train-steps 65536] [--mujoco-max-envs 256] [--out outputs/safe_nav_warp_speed.json]

Rows: ``env.physics=mjwarp`` on ``--device`` (Warp's CPU device or a GPU) at each N, and
``env.physics=mujoco`` (MuJoCo in C on the CPU, one thread) at each N up to ``--mujoco-max-envs``
(it does N times the work of one env); then ppo_lag training steps/s through ``train()`` for both.
The measuring is in :mod:`lab.bench.safe_nav_rates`; figures and how they were taken:
docs/safe_nav.md.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import torch

from lab.bench.safe_nav_rates import env_rate, load, train_rate


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--task", default="PointGoal1")
    p.add_argument("--num-envs", type=int, nargs="+", default=[1, 16, 256, 1024, 4096, 16384])
    p.add_argument("--steps", type=int, default=200, help="timed env steps per row")
    p.add_argument("--mujoco-max-envs", type=int, default=256)
    p.add_argument("--train-num-envs", type=int, nargs="*", default=[16])
    p.add_argument("--train-steps", type=int, default=32768, help="0: no training rows")
    p.add_argument("--out", default="outputs/safe_nav_warp_speed.json")
    args = p.parse_args()
    torch.set_num_threads(1)
    rows = []

    def row(**fields) -> None:
        fields["load"] = load()
        rows.append(fields)
        print(json.dumps(fields), flush=True)

    for n in args.num_envs:
        r = env_rate(args.task, "mjwarp", n, args.steps, args.device)
        row(kind="env", physics="mjwarp", device=args.device, num_envs=n, **r)
        if n <= args.mujoco_max_envs:
            r = env_rate(args.task, "mujoco", n, args.steps, "cpu")
            row(kind="env", physics="mujoco", device="cpu", num_envs=n, **r)
    for n in args.train_num_envs if args.train_steps else []:
        rollout = max(32, args.train_steps // (8 * n))
        extra = [f"rollout_steps={rollout}"]
        sps = train_rate(args.task, "mjwarp", n, args.train_steps, args.device, extra)
        row(kind="train", physics="mjwarp", device=args.device, num_envs=n, steps_per_s=sps)
        if n <= args.mujoco_max_envs:
            sps = train_rate(args.task, "mujoco", n, args.train_steps, "cpu", extra)
            row(kind="train", physics="mujoco", device="cpu", num_envs=n, steps_per_s=sps)
    os.makedirs(Path(args.out).parent, exist_ok=True)
    Path(args.out).write_text(json.dumps({"args": vars(args), "rows": rows}, indent=1))
    print("| kind | physics | device | N | steps/s | warm-up s | load |\n|---|---|---|--:|--:|--:|--:|")
    for r in rows:
        warm = f"{r['warmup_s']:.1f}" if "warmup_s" in r else ""
        line = f"| {r['kind']} | {r['physics']} | {r['device']} | {r['num_envs']} | {r['steps_per_s']:,.0f} | {warm} |"
        print(f"{line} {r['load']} |")
