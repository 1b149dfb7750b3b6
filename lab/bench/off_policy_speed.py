"""CPU cost of an off-policy gradient step: sac_lag and td3_lag on HalfCheetah velocity with the
benchmark's settings (configs/experiment/off_policy_benchmark.yaml and
configs/tuning/algo/velocity_sac_lag.yaml: 256 x 256 ReLU networks, batch 256, utd_ratio 1, 8 envs
x 8 steps per iteration), one torch thread.

    python experiments/speed/off_policy_speed.py [--iterations 15] [--algos sac_lag td3_lag] [--lambda-init 0.5] [--profile]

Per algorithm: the buffer is filled by the warm-up (random actions), then ``iterations`` iterations
of collect + update run through the trainer's pieces. It prints this process's CPU time
(``time.process_time``, what a free core would give on a shared machine) per gradient step inside
``algo.update``, and env steps per CPU second for collection and update together, with the load
average, and the float32 matmul rate of one thread (the step is mostly 256-wide matmuls: about
0.8 GFLOP a SAC step, docs/off_policy.md). ``--profile``: cProfile's top entries of the timed updates instead. Before/after figures of
a change are two runs of this script on the two commits (docs/off_policy.md, "Speed").
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import time

import torch

from cmdp_rl.algos import make_algo
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.envs import make_env
from cmdp_rl.policies import make_agent
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.rollout.normalization import make_normalizers

# td3_lag has no tuning file of its own: the same networks as sac_lag's preset.
NETWORKS = ["policy.hidden_sizes=[256,256]", "policy.activation=relu"]


def measure(algo_name: str, iterations: int, profile: bool, lambda_init: float) -> None:
    cfg = compose_config(
        [
            "+experiment=off_policy_benchmark",
            f"algo={algo_name}",
            *NETWORKS,
            "threads=1",
            f"algo.multiplier.init={lambda_init}",
        ]
    )
    torch.manual_seed(0)
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env, make_normalizers(cfg, env), algo=cfg.algo)
    algo = make_algo(cfg.algo, agent)
    collector = Collector(env, agent, cfg.rollout_steps, seed=0, uniform_steps=cfg.algo.warmup_steps)

    def iteration() -> tuple[float, int]:
        batch = collector.collect()
        agent.normalizers.scale_batch(batch)
        start = time.process_time()
        stats = algo.update(batch)
        spent = time.process_time() - start
        agent.normalizers.update_observation_stats(batch)
        return spent, int(stats["gradient_steps"])

    while collector.total_steps < cfg.algo.warmup_steps:  # random actions, no gradient step
        iteration()
    iteration()  # the first updates (allocations, lazy initialisation) are not timed
    profiler = cProfile.Profile() if profile else None
    cpu, steps, update_cpu, grad_steps = time.process_time(), collector.total_steps, 0.0, 0
    if profiler:
        profiler.enable()
    for _ in range(iterations):
        spent, n = iteration()
        update_cpu += spent
        grad_steps += n
    if profiler:
        profiler.disable()
    cpu, steps = time.process_time() - cpu, collector.total_steps - steps
    load = os.getloadavg()
    print(
        f"{algo_name} (lambda_init {lambda_init:g}): {1000 * update_cpu / grad_steps:.2f} ms CPU per gradient step ({grad_steps} steps), "
        f"{steps / cpu:.1f} env steps per CPU second ({steps} steps, {cpu:.1f} s CPU); "
        f"load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}",
        flush=True,
    )
    if profiler:
        pstats.Stats(profiler).sort_stats("tottime").print_stats(25)
    env.close()


def matmul_rate(size: int = 256, repeats: int = 300) -> float:
    """GFLOP/s of one [size, size] x [size, size] float32 matmul on one thread (the floor's unit:
    a 256 x 256 layer at batch 256)."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    for _ in range(20):
        a @ b
    start = time.process_time()
    for _ in range(repeats):
        a @ b
    return 2 * size**3 * repeats / (time.process_time() - start) / 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=15, help="timed iterations (64 env steps each)")
    parser.add_argument("--algos", nargs="+", default=["sac_lag", "td3_lag"])
    parser.add_argument("--profile", action="store_true", help="cProfile the timed updates")
    parser.add_argument(
        "--lambda-init",
        type=float,
        default=0.0,
        help="> 0: the multiplier is positive from the start, so the actor's step goes "
        "through the cost critic (at 0 it reads Q_c without a graph)",
    )
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread(s) before the config applies 1")
    torch.set_num_threads(1)
    print(f"float32 matmul 256^3 on one thread: {matmul_rate():.0f} GFLOP/s", flush=True)
    for name in args.algos:
        measure(name, args.iterations, args.profile, args.lambda_init)


if __name__ == "__main__":
    main()
