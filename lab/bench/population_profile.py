"""Where a population iteration's time goes: ms of process CPU time per part, per iteration.

    python experiments/speed/population_profile.py [--agents 64] [--envs 64] [--iterations 4]

Trains the population of ``population_benchmark.py`` (ppo_lag, ``env=reach1d_torch``) with the
named functions wrapped in ``time.process_time`` and prints the mean of iterations 2.. per part:
rollout, GAE, and inside the update the networks' forward, the backward, Adam, clipping and the rest.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import time
from pathlib import Path

import torch

from cmdp_rl import train  # noqa: E402
from cmdp_rl.population import learner, population, stacked  # noqa: E402
from cmdp_rl.rollout import advantages, collector  # noqa: E402
from lab.bench.population_benchmark import base, composed  # noqa: E402

PARTS = [
    (collector.Collector, "collect", "rollout (Collector.collect)"),
    (advantages.TwinGAE, "__call__", "GAE (critic values + torchrl GAE)"),
    (learner.StackedLearner, "update", "update() total (GAE included)"),
    (stacked.PopulationAgent, "training_pass", "  forward: the 3P networks"),
    (learner.StackedLearner, "step", "  optimiser steps total"),
    (torch.Tensor, "backward", "    backward (losses + networks)"),
    (stacked.StackedParams, "clip_grad_norm_", "    grad-norm clipping"),
    (stacked.StackedAdam, "step", "    Adam (stacked)"),
]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--agents", type=int, default=64)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--iterations", type=int, default=4)
    args = parser.parse_args()
    spent: dict[str, float] = collections.defaultdict(float)
    iteration = [0]

    def wrap(owner, name: str, label: str) -> None:
        f = getattr(owner, name)

        def timed(*a, **k):
            if label.startswith("rollout"):
                iteration[0] += 1
            t = time.process_time()
            r = f(*a, **k)
            if iteration[0] >= 2:  # the first iteration warms up
                spent[label] += time.process_time() - t
            return r

        setattr(owner, name, timed)

    for owner, name, label in PARTS:
        wrap(owner, name, label)
    raw = composed(base(args.envs, args.iterations, "cpu", 1) + [f"population.seeds={args.agents}"])
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as d:
        train(population(raw), Path(d) / "pop", echo=lambda s: None)
    n = max(1, args.iterations - 1)
    print(f"P = {args.agents} agents x {args.envs} envs, ms of CPU time per iteration (mean of iterations 2..):")
    for _, _, label in PARTS:
        print(f"  {label:40s} {spent[label] / n * 1e3:9.1f}")
    print(f"load average before {load}, after {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
