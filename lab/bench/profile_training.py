"""Profile end-to-end training with cProfile on CPU time: where does a training step go?

    python experiments/speed/profile_training.py env=reach1d_torch total_steps=131072 [--top 30]

Takes ``train.py``'s overrides, runs :func:`cmdp_rl.train` under cProfile (timer: this process's
CPU time, so other processes on the machine do not inflate the figures) and prints the functions
with the most own time, then the collector's and the update's shares of the total.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile
import time

import torch

import cmdp_rl
from cmdp_rl.config.run_config import compose_config


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("overrides", nargs="*", help="train.py overrides, e.g. env=reach1d_torch total_steps=131072")
    p.add_argument("--top", type=int, default=30)
    args = p.parse_args()
    cfg = compose_config(args.overrides)
    cfg.eval_episodes = 1
    torch.set_num_threads(cfg.threads)
    prof = cProfile.Profile(time.process_time)
    with tempfile.TemporaryDirectory() as out:
        prof.runcall(cmdp_rl.train, cfg, out, echo=lambda line: None)
    stats = pstats.Stats(prof)
    stats.sort_stats("tottime").print_stats(args.top)
    total = stats.total_tt
    parts = (
        ("rollout (Collector.collect)", "collector.py", "collect"),
        ("update (PPO.update, GAE included)", "ppo.py", "update"),
        ("  of which GAE (TwinGAE)", "advantages.py", "__call__"),
    )
    for label, file, fn in parts:
        cum = sum(v[3] for k, v in stats.stats.items() if k[0].endswith(file) and k[2] == fn)
        print(f"{label:36s} {cum:7.2f} s CPU of {total:.2f} s ({cum / total:.0%})")


if __name__ == "__main__":
    main()
