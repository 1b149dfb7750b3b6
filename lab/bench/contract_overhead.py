"""What the per-rollout env-contract check (``envs/contract.py: check_rollout``) costs in training
throughput, measured with ``benchmark_throughput.train_rate`` on the batched Reach1D settings.

    python experiments/speed/contract_overhead.py [--pairs 6] [--iterations 10]

Runs with the check off (``loop.check_rollout`` replaced by a no-op) and on alternate in one
process, the order flipped every pair so that drift in the machine's load falls on both; reports
the median steps/s (``metrics.csv``'s ``sps``, after the warm-up iteration) of each and their ratio,
with the load average before and after. On a shared machine those whole-run figures move by more
than the check costs, so the check is also timed alone: ``check_rollout`` on a batch the setting's
collector gathered (median of many calls), as a fraction of the iteration time at the setting's
median steps/s with the check on. Also times the one-off check before training.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import cmdp_rl.run.loop as loop  # noqa: E402
import cmdp_rl.run.start as start  # noqa: E402
from cmdp_rl import Collector, make_agent, make_env  # noqa: E402
from cmdp_rl.config.run_config import compose_config  # noqa: E402
from cmdp_rl.envs.contract import check_rollout  # noqa: E402
from lab.bench.throughput_rates import train_rate  # noqa: E402


def check_seconds(cfg, calls: int = 200) -> float:
    """Median wall time of ``check_rollout`` on one collected batch of ``cfg``'s shape."""
    env = make_env(cfg.env)
    batch = Collector(env, make_agent(cfg.policy, env), cfg.rollout_steps, seed=0).collect()
    env.close()
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        check_rollout(batch, "bench", False, 1)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


SETTINGS = {
    "torch N=1024 (env=reach1d_torch)": ["env=reach1d_torch"],
    "torch N=1024, env=reach1d defaults": ["env=reach1d", "env.backend=torch", "env.num_envs=1024"],
    "gym N=8 (env=reach1d)": ["env=reach1d"],
}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--pairs", type=int, default=6)
    p.add_argument("--iterations", type=int, default=10)
    args = p.parse_args(argv)
    real = loop.check_rollout
    print(f"load average before: {os.getloadavg()}")
    for name, overrides in SETTINGS.items():
        cfg = compose_config(["algo=ppo_lag", *overrides])
        t0 = time.perf_counter()
        start.check_env_contract(cfg)
        once = time.perf_counter() - t0
        sps: dict[str, list[float]] = {"off": [], "on": []}
        for pair in range(args.pairs):
            for mode in ("off", "on") if pair % 2 == 0 else ("on", "off"):
                loop.check_rollout = real if mode == "on" else (lambda *a, **k: None)
                sps[mode].append(train_rate(overrides, args.iterations, "cpu", 1)["train_sps"])
        loop.check_rollout = real
        off, on = statistics.median(sps["off"]), statistics.median(sps["on"])
        per_iter = cfg.rollout_steps * cfg.env.num_envs
        alone = check_seconds(cfg)
        print(
            f"{name}: check off {off:,.0f} steps/s, on {on:,.0f} steps/s, on/off {on / off:.4f} "
            f"(medians of {args.pairs} runs each; per-run off {[round(x) for x in sps['off']]}, "
            f"on {[round(x) for x in sps['on']]}); check alone {alone * 1e6:.0f} us per batch of {per_iter} "
            f"steps = {alone / (per_iter / on):.3%} of an iteration at {on:,.0f} steps/s; "
            f"the check before training took {once * 1000:.0f} ms"
        )
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
