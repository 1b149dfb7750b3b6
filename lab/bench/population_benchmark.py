"""Population training against the same agents trained one after another, in one process.

    python experiments/speed/population_benchmark.py [--agents 64] [--envs 64] [--iterations 3]
        [--scan 1,4,16,64,128] [--device cpu|cuda] [--threads 1] [--final-policy auto|last|...]
        [--out outputs/population_benchmark.json]

- together: ``--agents`` ppo_lag agents (the ``env=reach1d_torch`` preset with ``--envs`` envs each,
  one seed per agent) trained by ``train(population(raw))`` for ``--iterations`` iterations; summed
  training steps/s = agents x steps per agent / training wall time (evaluation excluded);
- one after another: the same agents' configs through ``train()``, in this process, one by one;
  summed steps/s = the same steps / the sum of their training times (``eval.json``'s
  ``train_time_s``); and the ratio;
- scan: summed steps/s of populations of each size in ``--scan`` (same shapes): where it stops
  growing with P, the update is bound by arithmetic, not by per-operation overhead;
- layers: one forward + backward of the agents' 3-layer MLPs on a minibatch, as batched matmuls
  (``torch.baddbmm``, what population/stacked.py uses) and as ``torch.func.functional_call`` under
  ``vmap`` over the stacked parameters, per population size (the fastest of many repetitions).

Prints a table and writes the figures, with the load average before and after, as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]  # the checkout: outputs/ goes there

from cmdp_rl import train  # noqa: E402
from cmdp_rl.config.run_config import CONFIG_DIR  # noqa: E402
from cmdp_rl.population import population  # noqa: E402
from cmdp_rl.population.spec import agent_configs  # noqa: E402


def composed(overrides: list[str]) -> dict:
    """The config ``train.py <overrides>`` composes, as a plain mapping (population node included)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return OmegaConf.to_container(compose("config", overrides=overrides), resolve=True)


def base(envs: int, iterations: int, device: str, threads: int, final_policy: str = "last") -> list[str]:
    steps = iterations * envs * max(32, min(256, 2048 // envs))
    return [
        f"deploy.policy={final_policy}",
        "algo=ppo_lag",
        "env=reach1d_torch",
        f"env.num_envs={envs}",
        f"total_steps={steps}",
        f"device={device}",
        f"threads={threads}",
        "eval_episodes=4",
        "log_interval=1000",
        "checkpoint_every=1000",
    ]


def _shape(args) -> tuple:
    return args.envs, args.iterations, args.device, args.threads, args.final_policy


def together(args, agents: int, tmp: Path) -> dict:
    raw = composed(base(*_shape(args)) + [f"population.seeds={agents}"])
    cpu = time.process_time()
    summary = train(population(raw), Path(tempfile.mkdtemp(prefix=f"pop{agents}_", dir=tmp)), echo=lambda s: None)
    cpu = time.process_time() - cpu
    return {
        "agents": agents,
        "train_time_s": summary["train_time_s"],
        "steps_summed": summary["steps_summed"],
        "summed_steps_per_s": summary["summed_steps_per_s"],
        "cpu_s": cpu,
        "steps_per_cpu_s": summary["steps_summed"] / cpu,
    }


def one_after_another(args, tmp: Path) -> dict:
    raw = composed(base(*_shape(args)) + [f"population.seeds={args.agents}"])
    _, cfgs = agent_configs(raw)
    total_time, steps = 0.0, 0
    cpu = time.process_time()
    for i, cfg in enumerate(cfgs):
        result = train(cfg, tmp / f"single{i}", echo=lambda s: None)
        total_time += result["train_time_s"]
        steps += result["steps"]
    cpu = time.process_time() - cpu
    return {
        "agents": len(cfgs),
        "train_time_s": total_time,
        "steps_summed": steps,
        "summed_steps_per_s": steps / total_time,
        "cpu_s": cpu,
        "steps_per_cpu_s": steps / cpu,
    }


def layers(sizes: list[int], rows: int, hidden: int, device: str) -> list[dict]:
    """Forward + backward of a 2 -> hidden -> hidden -> 1 tanh MLP per agent, both ways."""
    from torch.func import functional_call, vmap

    out = []
    for p in sizes:
        net = torch.nn.Sequential(
            torch.nn.Linear(2, hidden),
            torch.nn.Tanh(),
            torch.nn.Linear(hidden, hidden),
            torch.nn.Tanh(),
            torch.nn.Linear(hidden, 1),
        ).to(device)
        stacked = {
            k: v.detach().unsqueeze(0).repeat(p, *([1] * v.dim())).requires_grad_(True)
            for k, v in net.named_parameters()
        }
        x = torch.randn(p, rows, 2, device=device)

        def bmm() -> torch.Tensor:
            h = x
            for i in (0, 2, 4):
                h = torch.baddbmm(stacked[f"{i}.bias"].unsqueeze(1), h, stacked[f"{i}.weight"].transpose(1, 2))
                h = torch.tanh(h) if i < 4 else h
            return h

        def func() -> torch.Tensor:
            return vmap(lambda params, xi: functional_call(net, params, (xi,)))(stacked, x)

        timing = {}
        for name, fn in (("baddbmm", bmm), ("vmap", func)):
            for _ in range(3):
                fn().sum().backward()
            best = float("inf")  # the fastest of many: the least disturbed by other processes
            for _ in range(max(10, 400 // p)):
                t0 = time.perf_counter()
                fn().sum().backward()
                if device == "cuda":
                    torch.cuda.synchronize()
                best = min(best, time.perf_counter() - t0)
            timing[name] = best * 1e3
        out.append(
            {"agents": p, "rows": rows, "hidden": hidden, "baddbmm_ms": timing["baddbmm"], "vmap_ms": timing["vmap"]}
        )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--agents", type=int, default=64)
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--scan", default="1,4,16,64,128")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--final-policy",
        default="last",
        choices=["auto", "last", "average", "mixture"],
        help="every agent's deploy.policy (last, as every figure before: the training alone; auto: ppo_lag's "
        "valued mixture, whose valuation, per agent on both sides, runs in the last update)",
    )
    parser.add_argument("--skip-sequential", action="store_true", help="only the population side (and the scan)")
    parser.add_argument("--skip-layers", action="store_true", help="leave out the baddbmm / vmap comparison")
    parser.add_argument("--out", type=Path, default=ROOT / "outputs" / "population_benchmark.json")
    args = parser.parse_args(argv)
    report: dict = {
        "load_before": os.getloadavg(),
        "device": args.device,
        "threads": args.threads,
        "cpu": platform.processor() or platform.machine(),
        "envs_per_agent": args.envs,
        "iterations": args.iterations,
        "final_policy": args.final_policy,
    }
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        report["layers"] = (
            [] if args.skip_layers else layers([int(p) for p in args.scan.split(",")], 256, 32, args.device)
        )
        print("one forward + backward of every agent's 32 x 32 MLP on 256 rows (ms): baddbmm | vmap")
        for r in report["layers"]:
            print(f"  P = {r['agents']:4d}: {r['baddbmm_ms']:8.2f} | {r['vmap_ms']:8.2f}")
        report["together"] = together(args, args.agents, tmp)
        t = report["together"]
        print(
            f"together: {t['agents']} agents x {args.envs} envs: {t['summed_steps_per_s']:,.0f} summed steps/s "
            f"({t['steps_summed']:,} steps in {t['train_time_s']:.1f} s)"
        )
        if not args.skip_sequential:
            report["one_after_another"] = s = one_after_another(args, tmp)
            report["ratio"] = t["summed_steps_per_s"] / s["summed_steps_per_s"]
            report["ratio_cpu"] = t["steps_per_cpu_s"] / s["steps_per_cpu_s"]
            print(
                f"one after another: {s['summed_steps_per_s']:,.0f} summed steps/s "
                f"({s['steps_summed']:,} steps in {s['train_time_s']:.1f} s); ratio {report['ratio']:.1f}x"
            )
            print(
                f"per CPU-second of the whole calls (setup and evaluation included; less sensitive to other "
                f"processes): together {t['steps_per_cpu_s']:,.0f}, one after another {s['steps_per_cpu_s']:,.0f}; "
                f"ratio {report['ratio_cpu']:.1f}x"
            )
        report["scan"] = []
        for p in [int(p) for p in args.scan.split(",")]:
            r = together(args, p, tmp)
            report["scan"].append(r)
            print(
                f"scan: P = {p:4d}: {r['summed_steps_per_s']:>12,.0f} summed steps/s, "
                f"{r['summed_steps_per_s'] / p:>10,.0f} per agent; {r['steps_per_cpu_s']:>10,.0f} per CPU-second"
            )
    report["load_after"] = os.getloadavg()
    print(f"load average before {report['load_before']}, after {report['load_after']}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
