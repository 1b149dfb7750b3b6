"""The seed's probe exercise: memoryless and history-dependent policies, with and without a probe.

    python experiments/studies/probe_belief.py --run [overrides]   # the sweep (train.py -m +experiment=probe_belief), then the report
    python experiments/studies/probe_belief.py SWEEP_DIR           # the report from a finished sweep's runs

The sweep is ``configs/experiment/probe_belief.yaml`` ({mlp, lstm, transformer} x {probe, no probe}
x 3 seeds, the same steps each, PPO-Lagrangian on a noisy Reach1D with a passable wall; the file
says which settings and why). Each run writes train.py's outputs under
``multirun/probe_belief/<time>/<policy>_probe<bool>_s<seed>/``. The report adds ``probe.json`` to
each run (how often its trained, stochastic policy probes, overall and by step of the episode,
from its checkpoint; nothing is re-trained) and writes into the sweep directory:

- ``table.md`` / ``table.csv``: per policy head and probe option, mean ± std over seeds of the final
  policy's return, cost and goal rate (eval.json), its probe rate, and training steps/s.
- ``cost_vs_return.png``: every run's final cost against its return, with the group means.

``docs/probe_belief.md`` explains the result in terms of belief states.
"""

from __future__ import annotations

import dataclasses
import json
import statistics
from pathlib import Path
from typing import Any

import torch

from cmdp_rl import Collector, RunConfig, load_config, make_agent, make_env
from cmdp_rl.report.plot import pyplot, save_figure
from cmdp_rl.rollout import keys
from cmdp_rl.run.checkpoint import load_checkpoint
from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET
from cmdp_rl.run.migrations import member, migrate
from lab.studies import tables
from lab.studies.stats import population_mean_std
from lab.studies.tables import markdown_table, pm
from lab.sweeps import experiment_arg_parser, experiment_sweep_dir, finished_runs

ROOT = Path(__file__).resolve().parents[2]  # the checkout: its train.py, Makefile, docs/ and multirun/
POLICY_ORDER = ("mlp", "lstm", "gru", "transformer")
EARLY_STEPS = 5  # "early" = the first steps of an episode, where a belief-building agent probes
PROBE_STEPS = 64  # steps per env of the trained stochastic policy in which its probes are counted


@torch.no_grad()
def probe_stats(cfg: RunConfig, run_dir: Path, steps: int) -> dict[str, Any]:
    """How often the run's final stochastic policy probes (2nd action dimension > 0, the env's own
    test), over ``steps`` steps of every env: overall, in the first steps of an episode and later."""
    if not cfg.env.probe:
        return {"probe_rate": None, "probe_rate_early": None, "probe_rate_later": None}
    state = load_checkpoint(run_dir / "checkpoint.pt", policy=cfg.policy.name)
    env = make_env(dataclasses.replace(cfg.env, stagger=False), device=cfg.device)
    ac = make_agent(cfg.policy, env)
    ac.load_state_dict(member(migrate(state, ac))["algo_state"]["networks"])  # older formats too
    batch = Collector(env, ac, steps, seed=cfg.seed + EVAL_SEED_OFFSET + 1).collect()
    env.close()
    probing = batch.get(keys.ACTION)[..., 1] > 0
    step_in_episode = batch.get((keys.NEXT, keys.EPISODE_LENGTH)).squeeze(-1) - 1
    early = step_in_episode < EARLY_STEPS
    return {
        "probe_rate": probing.float().mean().item(),
        "probe_rate_early": probing[early].float().mean().item(),
        "probe_rate_later": probing[~early].float().mean().item() if (~early).any() else None,
        "early_steps": EARLY_STEPS,
        "steps": int(probing.numel()),
    }


def load_runs(sweep_dir: Path, probe_steps: int = PROBE_STEPS) -> list[dict[str, Any]]:
    """Every finished run under ``sweep_dir``: config, eval.json, probe.json (written first where
    missing, from the run's checkpoint) and metrics rows."""
    runs = []
    for run in finished_runs(sweep_dir):
        run_dir, cfg = run.path, run.config
        probe_path = run_dir / "probe.json"
        if not probe_path.is_file():
            run_cfg = load_config(cfg)
            probe_path.write_text(json.dumps(probe_stats(run_cfg, run_dir, probe_steps), indent=2))
        runs.append(
            {
                "dir": run_dir,
                "policy": cfg["policy"]["name"],
                "probe": bool(cfg["env"]["probe"]),
                "seed": cfg["seed"],
                "eval": run.eval,
                "probe_stats": json.loads(probe_path.read_text()),
                "rows": run.metrics,
            }
        )
    return runs


def _train_sps(rows: list[dict[str, float]]) -> float:
    """Median steps/s over the iterations after the first (which pays for warm-up)."""
    sps = [r["sps"] for r in rows[1:]] or [r["sps"] for r in rows]
    return statistics.median(sps)


def _group_key(run: dict[str, Any]) -> tuple[int, bool]:
    order = POLICY_ORDER.index(run["policy"]) if run["policy"] in POLICY_ORDER else len(POLICY_ORDER)
    return order, run["probe"]


def summarize(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (policy head, probe option): means and spreads over its seeds."""
    groups: dict[tuple[str, bool], list[dict[str, Any]]] = {}
    for run in sorted(runs, key=_group_key):
        groups.setdefault((run["policy"], run["probe"]), []).append(run)
    table = []
    for (policy, probe), group in groups.items():
        row: dict[str, Any] = {
            "policy": policy,
            "probe": probe,
            "seeds": len(group),
            "steps": group[0]["eval"]["steps"],
            "cost_limit": group[0]["eval"]["cost_limit"],
        }
        for key in ("episode_return", "episode_cost", "goal_reached", "episode_length"):
            row[key], row[f"{key}_std"] = population_mean_std([r["eval"][key] for r in group])
        for key in ("probe_rate", "probe_rate_early", "probe_rate_later"):
            row[key], row[f"{key}_std"] = population_mean_std(
                [r["probe_stats"][key] for r in group if r["probe_stats"].get(key) is not None]
            )
        row["train_sps"], row["train_sps_std"] = population_mean_std([_train_sps(r["rows"]) for r in group])
        table.append(row)
    return table


def write_table(table: list[dict[str, Any]], out: Path) -> str:
    header = [
        "policy",
        "probe",
        "seeds",
        "steps",
        "return",
        "cost",
        "goal reached",
        "episode length",
        "probe rate",
        "probe rate, first 5 steps",
        "probe rate, later",
        "training steps/s",
    ]
    cells = [
        [
            r["policy"],
            "yes" if r["probe"] else "no",
            str(r["seeds"]),
            f"{r['steps']:,}",
            pm(r["episode_return"], r["episode_return_std"], ".3f"),
            pm(r["episode_cost"], r["episode_cost_std"], ".3f"),
            pm(r["goal_reached"], r["goal_reached_std"], ".2f"),
            pm(r["episode_length"], r["episode_length_std"], ".1f"),
            pm(r["probe_rate"], r["probe_rate_std"], ".2f"),
            pm(r["probe_rate_early"], r["probe_rate_early_std"], ".2f"),
            pm(r["probe_rate_later"], r["probe_rate_later_std"], ".2f"),
            pm(r["train_sps"], r["train_sps_std"], ",.0f"),
        ]
        for r in table
    ]
    limit = table[0]["cost_limit"] if table else float("nan")
    text = markdown_table(header, cells) + (
        f"\n\nBudget d = {limit:g} crossing per episode. Return, cost, goal rate and length: the final stochastic "
        f"policy over eval_episodes episodes (eval.json); probe rate: fraction of its steps that were probes "
        f"(probe.json); mean ± std over seeds. Training steps/s: median over iterations, on a shared 2-core "
        f"machine (noisy).\n"
    )
    return tables.write_table(out, text, table)


def plot_cost_vs_return(runs: list[dict[str, Any]], table: list[dict[str, Any]], out: Path) -> Path:
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(7.5, 5.2))
    colors = {}
    for row in table:
        policy, probe = row["policy"], row["probe"]
        group = [r for r in runs if r["policy"] == policy and r["probe"] == probe]
        color = colors.setdefault(policy, f"C{len(colors)}")
        marker = "o" if probe else "s"
        face = color if probe else "none"
        ax.scatter(
            [r["eval"]["episode_return"] for r in group],
            [r["eval"]["episode_cost"] for r in group],
            marker=marker,
            facecolors=face,
            edgecolors=color,
            s=28,
            alpha=0.6,
        )
        ax.errorbar(
            row["episode_return"],
            row["episode_cost"],
            xerr=row["episode_return_std"],
            yerr=row["episode_cost_std"],
            fmt=marker,
            color=color,
            mfc=face,
            ms=10,
            capsize=3,
            label=f"{policy}, {'probe' if probe else 'no probe'} ({row['seeds']} seed{'s' if row['seeds'] > 1 else ''})",
        )
    limit = table[0]["cost_limit"]
    ax.axhline(limit, color="k", linestyle="--", linewidth=1, label=f"budget d = {limit:g}")
    ax.set_xlabel("episode return (final policy, sampled actions)")
    ax.set_ylabel("episode cost = wall crossings")
    ax.set_title("Reach1D, passable wall, obs noise 0.3: small markers = seeds, large = mean ± std")
    ax.title.set_fontsize(9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, out / "cost_vs_return.png", dpi=120)


def gather(sweep_dir: Path, probe_steps: int = PROBE_STEPS) -> str:
    runs = load_runs(sweep_dir, probe_steps)
    if not runs:
        raise SystemExit(f"no finished runs (eval.json) under {sweep_dir}")
    table = summarize(runs)
    text = write_table(table, sweep_dir)
    png = plot_cost_vs_return(runs, table, sweep_dir)
    print(f"\n{text}\nwrote {sweep_dir / 'table.md'}, {sweep_dir / 'table.csv'}, {png}")
    return text


def main() -> None:
    parser = experiment_arg_parser(__doc__)
    parser.add_argument("--probe-steps", type=int, default=PROBE_STEPS, help="steps per env for the probe rate")
    args = parser.parse_args()
    sweep_dir = experiment_sweep_dir(parser, args, "probe_belief", ROOT)
    gather(Path(sweep_dir), args.probe_steps)


if __name__ == "__main__":
    main()
