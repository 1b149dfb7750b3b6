"""Size and save time of a checkpoint that holds a replay buffer: sac_lag on HalfCheetah velocity
with the benchmark's settings (configs/experiment/off_policy_benchmark.yaml and
configs/tuning/algo/velocity_sac_lag.yaml: 256 x 256 networks, 8 envs x 8 steps per iteration).

    python experiments/speed/checkpoint_cost.py [--transitions 100032] [--updates 8] [--repeats 15] [--out DIR]

The buffer is filled with ``transitions`` transitions by the warm-up (random actions, no gradient
step), then ``updates`` iterations of collect + update run, so that the optimizers hold their
moments, as in a checkpoint of a real run. Then the checkpoint the trainer writes (the same fields,
``trainer.py``) is assembled and written ``repeats`` times; the script prints the file's size and
the wall time of each write (assembling the state included: that is what a run waits for), with
the load average. Before/after figures of a change are two runs of this script on the two commits
(docs/checkpoints.md).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import torch

from cmdp_rl.algos import make_algo
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.envs import make_env
from cmdp_rl.policies import make_agent
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.rollout.normalization import make_normalizers
from cmdp_rl.run.checkpoint import checkpoint_state, member_entry, save_checkpoint
from cmdp_rl.run.rng import rng_state, seed_everything


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--transitions", type=int, default=100_032, help="transitions in the buffer (warm-up)")
    parser.add_argument("--updates", type=int, default=8, help="iterations with gradient steps after the warm-up")
    parser.add_argument("--repeats", type=int, default=15, help="checkpoint writes timed")
    parser.add_argument("--out", default=None, help="directory for the checkpoint (default: a temp dir)")
    args = parser.parse_args()
    cfg = compose_config(
        [
            "+experiment=off_policy_benchmark",
            "algo=sac_lag",
            "threads=1",
            f"algo.warmup_steps={args.transitions}",
        ]
    )
    torch.set_num_threads(1)
    seed_everything(0)
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env, make_normalizers(cfg, env), algo=cfg.algo)
    algo = make_algo(cfg.algo, agent)
    collector = Collector(env, agent, cfg.rollout_steps, seed=0, uniform_steps=cfg.algo.warmup_steps)

    def iteration() -> None:
        batch = collector.collect()
        agent.normalizers.scale_batch(batch)
        algo.update(batch)
        agent.normalizers.update_observation_stats(batch)

    start = time.perf_counter()
    while collector.total_steps < args.transitions:
        iteration()
    for _ in range(args.updates):
        iteration()
    print(f"filled {collector.total_steps:,} transitions in {time.perf_counter() - start:.1f} s", flush=True)

    out = Path(args.out or tempfile.mkdtemp(prefix="checkpoint_cost_"))
    out.mkdir(parents=True, exist_ok=True)
    path = out / "checkpoint.pt"
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        save_checkpoint(
            path,
            checkpoint_state(
                cfg, 1, collector.total_steps, 0.0, [member_entry({}, algo)], collector.state_dict(), rng_state()
            ),
        )
        times.append(time.perf_counter() - t0)
    env.close()
    load = os.getloadavg()
    print(
        f"checkpoint {path}: {path.stat().st_size:,} bytes; save {statistics.median(times):.3f} s median, "
        f"{min(times):.3f} s min of {args.repeats} ({', '.join(f'{t:.3f}' for t in times)}); load average {load[0]:.2f}, {load[1]:.2f}, "
        f"{load[2]:.2f}",
        flush=True,
    )
