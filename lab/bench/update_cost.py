"""What one PPO update costs as its minibatches grow: is the update bound by per-op overhead or by
arithmetic?

    python experiments/speed/update_cost.py [train.py overrides] [--sizes 512 1024 2048 4096 8192]

Composes the config ``python train.py <overrides>`` runs (default: ``env=reach1d_torch``, ppo_lag),
collects one batch, then times ``algo.update`` on that same batch with one pass in minibatches of
each size (median of a few repeats, after a warm-up). The time includes GAE and the critics' values
for it, which do not depend on the minibatch size. Prints ms per update, per minibatch and µs per
step; ``docs/throughput.md`` quotes it.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from cmdp_rl import Collector, make_agent, make_algo, make_env
from cmdp_rl.config.run_config import compose_config
from lab.bench.throughput_rates import net_label


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("overrides", nargs="*", help="train.py overrides (default: env=reach1d_torch)")
    p.add_argument("--sizes", type=int, nargs="+", default=[512, 1024, 2048, 4096, 8192])
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    cfg = compose_config(["algo=ppo_lag", *(args.overrides or ["env=reach1d_torch"])])
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    env = make_env(cfg.env, device=cfg.device)
    ac = make_agent(cfg.policy, env, algo=cfg.algo)
    collector = Collector(env, ac, cfg.rollout_steps, seed=cfg.seed)
    batch = collector.collect()
    steps = batch.numel()
    print(
        f"{cfg.env.name} ({cfg.env.backend}, {env.num_envs} envs), {net_label(cfg.policy)}, batch {steps} steps, "
        f"one pass, {torch.get_num_threads()} thread(s)"
    )
    print(f"{'minibatch':>9s} {'minibatches':>11s} {'update ms':>9s} {'ms / minibatch':>14s} {'us / step':>9s}")
    for size in args.sizes:
        if steps % size:
            raise SystemExit(f"--sizes: {size} does not divide the batch of {steps} steps")
        cfg.algo.update_epochs, cfg.algo.num_minibatches = 1, steps // size
        algo = make_algo(cfg.algo, ac)
        times = []
        for _ in range(args.repeats + 1):  # the first is warm-up
            b = batch.clone()
            t0 = time.perf_counter()
            algo.update(b)
            times.append(time.perf_counter() - t0)
        ms = statistics.median(times[1:]) * 1e3
        print(f"{size:9d} {steps // size:11d} {ms:9.1f} {ms / (steps // size):14.2f} {ms / steps * 1e3:9.2f}")
    env.close()


if __name__ == "__main__":
    main()
