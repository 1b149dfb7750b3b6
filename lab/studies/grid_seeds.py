"""Train ``env=grid`` runs over several seeds, as ``python train.py env=grid algo=<algo> <overrides>``
would (the env=grid tuning presets included), and set each final policy against the LP optimum:
its sampled evaluation (eval.json) and its exact return and costs (lab/studies/grid_policy.py).

    python experiments/studies/grid_seeds.py --seeds 0 1 2 3 4 -- algo=ppo_lag
    python experiments/studies/grid_seeds.py --seeds 0 1 --jobs 2 -- algo=ppo_lag total_steps=60000

Prints one row per seed and the count of seeds within 10% of the optimum and within every budget
(exactly). Runs go under --out (a fresh temporary directory by default).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from cmdp_rl import train  # noqa: E402
from cmdp_rl.config.run_config import compose_config  # noqa: E402
from cmdp_rl.envs.grid.optimum import solve_constrained  # noqa: E402
from cmdp_rl.envs.grid.tabular import grid_cmdp  # noqa: E402
from cmdp_rl.run.rundir import load_trained  # noqa: E402
from lab.studies.grid_policy import exact_gap  # noqa: E402


def one_seed(overrides: list[str], seed: int, out: Path) -> dict:
    cfg = compose_config(["env=grid", *overrides, f"seed={seed}"])
    run = out / f"s{seed}"
    t0 = time.perf_counter()
    res = train(cfg, run, echo=lambda s: None)
    wall = time.perf_counter() - t0
    trained = load_trained(run)
    trained.env.close()
    env = cfg.env
    cmdp = grid_cmdp(tuple(env.layout), env.slip, env.end_prob)
    budgets = cfg.algo.cost_limit if isinstance(cfg.algo.cost_limit, list) else [cfg.algo.cost_limit] * 2
    g = exact_gap(trained.agent, cmdp, solve_constrained(cmdp, budgets))
    names = cmdp.cost_names
    return {
        "seed": seed,
        "wall_s": wall,
        "steps": res.get("total_steps", None),
        "eval_return": res["episode_return"],
        "eval_costs": [res[f"episode_cost/{n}"] for n in names],
        "eval_episodes": res["episodes"],
        "deterministic": res["deterministic"],
        "exact_return": g.ret,
        "exact_costs": list(g.costs),
        "optimum": g.optimum,
        "gap": g.gap,
        "budgets": list(g.budgets),
        "ok": g.within_budgets and g.gap <= 0.10,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("overrides", nargs="*")
    args = p.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="grid_seeds_"))
    print(f"python train.py env=grid {' '.join(args.overrides)}  (runs in {out})")
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(one_seed, [args.overrides] * len(args.seeds), args.seeds, [out] * len(args.seeds)))
    first = rows[0]
    print(
        f"LP optimum {first['optimum']:.4f} at budgets {first['budgets']}; eval over {first['eval_episodes']} "
        f"{'deterministic' if first['deterministic'] else 'sampled'} episodes"
    )
    print("seed | wall s | eval return | eval costs  | exact return | exact costs   | gap    | ok")
    for r in rows:
        print(
            f"{r['seed']:4d} | {r['wall_s']:6.1f} | {r['eval_return']:11.3f} | "
            f"{'/'.join(f'{c:.3f}' for c in r['eval_costs']):11s} | {r['exact_return']:12.4f} | "
            f"{'/'.join(f'{c:.4f}' for c in r['exact_costs']):13s} | {100 * r['gap']:5.1f}% | {r['ok']}"
        )
    print(f"{sum(r['ok'] for r in rows)}/{len(rows)} seeds within 10% of the optimum and within every budget (exact)")
    (out / "grid_seeds.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
