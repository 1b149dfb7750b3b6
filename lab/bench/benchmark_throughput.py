"""Throughput of the toolkit on Reach1D: env, rollout and end-to-end training steps per second.

    python experiments/speed/benchmark_throughput.py [--quick] [--device cpu|cuda] [--threads 1]
                                               [--out outputs/benchmark_throughput.json]

For each setting (the gymnasium Reach1D alone and in gymnasium's SyncVectorEnv of 8; the batched
``TorchReach1D`` with N = 64, 1024, 16384) it measures:

- env: raw steps/s of the env alone, on pre-drawn random actions;
- rollout: steps/s of the shared :class:`~cmdp_rl.Collector` (MLP policy sampling + env, no
  learning), and, for the SyncVectorEnv of 8, a plain Python loop over the same vector env and the
  same policy network, storing the same step data;
- train: ``ppo_lag`` with the MLP policy, through :func:`cmdp_rl.train` on the config
  ``train.py`` composes for the same overrides; steps/s as ``metrics.csv``'s ``sps`` column reports
  it (median over iterations after the first, which pays for warm-up);
- peak memory of each measurement (resident set; CUDA max allocated on cuda), torch's threads.

Gym settings train with the default config; batched settings with the ``env=reach1d_torch``
preset (``configs/env/reach1d_torch.yaml``; its batch shape is the "auto" one: rollouts of 32
steps, one pass in 64 minibatches; at N = 64, rollouts of 256 steps in the same 1 x 64 so that
minibatches are not tiny), tuning included (``configs/tuning/``: the MLP is 32 x 32 there, and the
rollout measurement runs the same network; the ``net`` column says which). One more row trains the
throughput target command as typed,
``env=reach1d env.backend=torch env.num_envs=1024`` (the reach1d defaults, batch shape "auto"),
and the LSTM and transformer heads at N = 1024 with the preset.

One table is printed and the same figures are written as JSON. Figures taken while other
processes share the CPU are noisy: the JSON records the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any

import torch

from lab.bench.throughput_rates import (
    CPU_SHARE,
    MEMORY_HEADS,
    Setting,
    env_rate,
    measure,
    plain_loop_rate,
    rollout_rate,
    train_rate,
)

ROOT = Path(__file__).resolve().parents[2]  # the checkout: outputs/ goes there


# --- the run -------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="a smoke run: tiny durations and iterations")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads (the config's default: 1)")
    p.add_argument("--out", default=str(ROOT / "outputs" / "benchmark_throughput.json"), help="JSON output path")
    p.add_argument(
        "--seconds", type=float, default=None, help="time per env/rollout measurement (default 2, quick 0.05)"
    )
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    seconds = args.seconds or (0.05 if args.quick else 2.0)
    load_before = os.getloadavg()
    started = time.perf_counter()

    preset = ["env=reach1d_torch"]
    settings = [
        Setting("gym", 1, 256, ["env=reach1d", "env.num_envs=1"]),
        Setting("gym", 8, 256, ["env=reach1d"]),
        Setting(
            "torch",
            64,
            256,
            [*preset, "env.num_envs=64", "rollout_steps=256", "algo.update_epochs=1", "algo.num_minibatches=64"],
        ),
        Setting("torch", 1024, 32, preset),
        Setting("torch", 16384, 32, [*preset, "env.num_envs=16384"]),
    ]
    # iterations of training per setting (the first is warm-up, not counted)
    train_iters = {1: 5, 8: 5, 64: 6, 1024: 10, 16384: 3}
    quick_train = ["rollout_steps=4", "algo.update_epochs=1", "algo.num_minibatches=1"]

    rows: list[dict[str, Any]] = []
    for s in settings:
        row: dict[str, Any] = {"setting": s.label, "backend": s.backend, "num_envs": s.num_envs}
        row["env_sps"], row["env_mem"] = measure("env", lambda: env_rate(s, seconds, args.device), args.device)
        row["rollout_sps"], row["rollout_mem"] = measure(
            "rollout", lambda: rollout_rate(s, s.rollout_steps, seconds, args.device), args.device
        )
        overrides = s.train_overrides + (quick_train if args.quick else [])
        iters = 2 if args.quick else train_iters[s.num_envs]
        train, row["train_mem"] = measure(
            "train", lambda: train_rate(overrides, iters, args.device, args.threads), args.device
        )
        row.update(train)
        row["train_over_rollout"] = row["train_sps"] / row["rollout_sps"]
        rows.append(row)

    extra: list[dict[str, Any]] = []
    # The target command: reach1d's defaults with only the backend and N changed (the batch
    # shape then follows N: rollout_steps, update_epochs and num_minibatches are "auto").
    literal_1024 = ["env=reach1d", "env.backend=torch", "env.num_envs=1024"]
    if args.quick:
        literal_1024 += quick_train
    t, mem = measure(
        "train", lambda: train_rate(literal_1024, 2 if args.quick else 10, args.device, args.threads), args.device
    )
    literal = {"setting": "torch N=1024, env=reach1d defaults", "train_mem": mem, **t}
    extra.append(literal)
    for head in MEMORY_HEADS:
        o = [*preset, f"policy={head}"] + (quick_train if args.quick else [])
        t, mem = measure("train", lambda: train_rate(o, 2 if args.quick else 4, args.device, args.threads), args.device)
        extra.append({"setting": f"torch N=1024, policy={head}", "train_mem": mem, **t})

    plain, plain_mem = measure("plain", lambda: plain_loop_rate(8, 256, seconds), "cpu")
    gym8 = next(r for r in rows if r["backend"] == "gym" and r["num_envs"] == 8)
    t1024 = next(r for r in rows if r["backend"] == "torch" and r["num_envs"] == 1024)
    result = {
        "meta": {
            "device": args.device,
            "torch_threads": torch.get_num_threads(),
            "quick": args.quick,
            "seconds_per_measurement": seconds,
            "torch": torch.__version__,
            "python": platform.python_version(),
            "cpu_count": os.cpu_count(),
            "loadavg_before": load_before,
            "loadavg_after": os.getloadavg(),
            # Below about 0.9 (one thread), other processes took CPU time from the measurement:
            # its steps/s are then lower than on a quiet machine by about this factor.
            "cpu_share_min": min(CPU_SHARE),
            "cpu_share_median": statistics.median(CPU_SHARE),
            "cpu_share_max": max(CPU_SHARE),
            "wall_s": time.perf_counter() - started,
            "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        },
        "rows": rows,
        "extra": extra,
        "plain_loop_sync8": {"rollout_sps": plain, "mem": plain_mem},
        "targets": {
            # as the issue states it: `train.py algo=ppo_lag env=reach1d env.backend=torch env.num_envs=1024`
            "train_sps_torch_1024": literal["train_sps"],
            "train_sps_torch_1024_ge_100k": literal["train_sps"] >= 100_000,
            "train_over_rollout_torch_1024": t1024["train_over_rollout"],
            "train_over_rollout_ge_0.3": t1024["train_over_rollout"] >= 0.3,
            "collector_over_plain_loop_sync8": gym8["rollout_sps"] / plain,
            "collector_over_plain_loop_ge_0.5": gym8["rollout_sps"] / plain >= 0.5,
        },
    }
    result["meta"]["wall_s"] = time.perf_counter() - started
    print_table(result)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    print(f"written to {out}")
    return result


def print_table(r: dict[str, Any]) -> None:
    m = r["meta"]
    mem_key = "cuda_max_allocated_mb" if m["device"] == "cuda" else "peak_rss_mb"
    print(
        f"\nthroughput on {m['device']}, torch {m['torch']}, {m['torch_threads']} thread(s), "
        f"load average {m['loadavg_before'][0]:.1f} -> {m['loadavg_after'][0]:.1f}, "
        f"CPU share of the measurements {m['cpu_share_min']:.2f}..{m['cpu_share_max']:.2f}"
        f"{' (machine busy: figures noisy and low)' if m['cpu_share_median'] < 0.9 * m['torch_threads'] else ''}"
        f"{' (QUICK smoke run: not meaningful)' if m['quick'] else ''}"
    )
    head = (
        f"{'setting':34s} {'env steps/s':>12s} {'rollout st/s':>12s} {'train st/s':>11s} {'train/roll':>10s}"
        f"  {'batch':>7s} {'ep x mb':>7s} {'net':>11s}  peak MB env/roll/train  CPU share env/roll/train"
    )
    print(head)
    print("-" * len(head))

    def mb(row: dict[str, Any], k: str) -> str:
        return f"{row[k][mem_key]:.0f}" if k in row else "-"

    for row in r["rows"]:
        print(
            f"{row['setting']:34s} {row['env_sps']:12,.0f} {row['rollout_sps']:12,.0f} {row['train_sps']:11,.0f}"
            f" {row['train_over_rollout']:10.2f}  {row['batch']:7d} {row['update_epochs']:>3d}x{row['num_minibatches']:<3d}"
            f" {row['net']:>11s}"
            f"  {mb(row, 'env_mem')}/{mb(row, 'rollout_mem')}/{mb(row, 'train_mem')}"
            f"  {row['env_mem']['cpu_share']:.2f}/{row['rollout_mem']['cpu_share']:.2f}/{row['train_mem']['cpu_share']:.2f}"
        )
    for row in r["extra"]:
        print(
            f"{row['setting']:34s} {'':>12s} {'':>12s} {row['train_sps']:11,.0f} {'':>10s}"
            f"  {row['batch']:7d} {row['update_epochs']:>3d}x{row['num_minibatches']:<3d} {row['net']:>11s}"
            f"  -/-/{mb(row, 'train_mem')}"
            f"  {row['train_mem']['cpu_share']:.2f}"
        )
    pl = r["plain_loop_sync8"]
    print(
        f"{'plain loop, gym N=8 (yardstick)':34s} {'':>12s} {pl['rollout_sps']:12,.0f}"
        f"{'':>40s}{pl['mem']['peak_rss_mb']:.0f}  {pl['mem']['cpu_share']:.2f}"
    )
    t = r["targets"]
    print(
        f"\ntargets: train sps torch N=1024 {t['train_sps_torch_1024']:,.0f} (>= 100,000: {t['train_sps_torch_1024_ge_100k']}); "
        f"train/rollout {t['train_over_rollout_torch_1024']:.2f} (>= 0.3: {t['train_over_rollout_ge_0.3']}); "
        f"collector/plain loop gym N=8 {t['collector_over_plain_loop_sync8']:.2f} (>= 0.5: {t['collector_over_plain_loop_ge_0.5']}); "
        f"benchmark took {m['wall_s']:.0f}s"
    )


if __name__ == "__main__":
    main()
