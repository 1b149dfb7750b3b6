"""The campaign's report from its records alone (lab/bench/campaign.py): docs/benchmarks.md's opening tables and
a figure of the training curves beside the published ones. No run is repeated, so the same records give the
same bytes: rows sorted, numbers formatted at fixed precision, the PNG written without a timestamp.

A record made with options other than today's defaults for its command line is marked stale with its date:
its config is compared with the one ``train.py`` would compose from the same overrides now.
"""

from __future__ import annotations

import json
import math
import statistics
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable, Sequence

import yaml

from lab.bench import published
from lab.bench.campaign import ROOT, Campaign

BEGIN = "<!-- campaign report: begin (python experiments/benchmarks/campaign.py CAMPAIGN... --report) -->"
END = "<!-- campaign report: end -->"
PAGE = ROOT / "docs" / "benchmarks.md"
FIGURE = ROOT / "docs" / "figures" / "safety_gym_campaign.png"
BUDGET = 25.0
HEADLINE_STEPS = 2_000_000  # the step count the page opens with (issue 51: the field's 2M comparison)
ONE_E7_STEPS = 10_000_000  # reported beside OmniSafe's 1e7 table, not in a table of its own
PEER_NAMES = {"PPOLag": "ppo_lag", "CPO": "cpo", "PPO": "ppo", "CPPOPID": "pid_lag"}


def read_records(campaigns: Sequence[Campaign]) -> list[dict[str, Any]]:
    """Every record of the campaigns' runs that exists, in the campaigns' order."""
    records, seen = [], set()
    for c in campaigns:
        for run in c.runs:
            path = c.results / f"{run.id}.json"
            if path.is_file() and path.resolve() not in seen:  # two campaigns may list the same run: one record
                seen.add(path.resolve())
                records.append(json.loads(path.read_text()))
    return records


def task_of(record: dict[str, Any]) -> str:
    """The task's short name: ``PointGoal1`` for safe_nav's and for Safety-Gymnasium's ``SafetyPointGoal1-v0``."""
    task = record["task"]
    return task.removeprefix("Safety").rsplit("-v", 1)[0]


def algo_of(record: dict[str, Any]) -> str:
    return PEER_NAMES.get(record["algo"], record["algo"].lower()) if record["toolkit"] != "cmdp_rl" else record["algo"]


def stale_since(record: dict[str, Any], cache: dict[tuple, Any]) -> str | None:
    """The record's date where its config is not what its command line composes to today, else None."""
    if record["toolkit"] != "cmdp_rl":
        return None
    key = (record["algo"], record["env"], record["task"], tuple(record["options"]))
    if key not in cache:
        cache[key] = today_config(record)
    now = cache[key]
    from cmdp_rl.run.migrations import saved_config_defaults

    # The record's config as it reads today (an option since removed, with the value it always had, is not a change).
    recorded = saved_config_defaults(record["config"])
    then = _plain({k: recorded.get(k) for k in now})
    return None if then == now else record["date"]


def today_config(record: dict[str, Any]) -> dict[str, Any]:
    from cmdp_rl.config.run_config import compose_config, validate
    from cmdp_rl.run.trainer import run_config

    task = [f"env.task={record['task']}"] if record["task"] else []
    overrides = [f"algo={record['algo']}", f"env={record['env']}", *task, f"total_steps={record['steps']}"]
    cfg = compose_config([*overrides, f"seed={record['seed']}", *record["options"]])
    validate(cfg)
    saved = run_config(cfg)
    return _plain({k: saved.get(k) for k in ("algo", "policy", "normalize", "deploy", "env", "rollout_steps")})


def _plain(value: Any) -> Any:
    """The YAML round trip config.yaml made: tuples as lists, floats as YAML reads them."""
    return yaml.safe_load(yaml.safe_dump(value, sort_keys=True))


# --- cells -------------------------------------------------------------------------------------------


def _fmt(values: Sequence[float], digits: int) -> str:
    """The mean over seeds, with the seeds' standard deviation where there are several."""
    values = [v for v in values if v is not None and not math.isnan(v)]
    if not values:
        return "–"
    mean = statistics.fmean(values)
    spread = f" ± {statistics.stdev(values):.{digits}f}" if len(values) > 1 else ""
    return f"{mean:.{digits}f}{spread}"


def pair(returns: Sequence[float], costs: Sequence[float]) -> str:
    return f"{_fmt(returns, 1)} / {_fmt(costs, 1)}"


def curve_at(record: dict[str, Any], step: int) -> dict[str, Any]:
    return next((p for p in record["curve"] if p["step"] == step), {})


def eval_cell(records: Sequence[dict[str, Any]], mode: str) -> str:
    evals = [r["evaluation"].get(mode) for r in records]
    evals = [e for e in evals if e]
    if not evals:
        return "–"
    ucb = max((e.get("episode_cost_ucb95") or e["episode_cost"]) for e in evals)
    return f"{pair([e['episode_return'] for e in evals], [e['episode_cost'] for e in evals])} (≤ {ucb:.1f})"


def cpu_per_million(records: Sequence[dict[str, Any]]) -> str:
    rates = [r["time"]["cpu_s"] / (r["steps"] / 1e6) for r in records if r["time"].get("cpu_s")]
    return f"{statistics.fmean(rates):,.0f}" if rates else "–"


def groups(records: Iterable[dict[str, Any]]) -> dict[tuple, list[dict[str, Any]]]:
    """Records by (steps, task, algo, toolkit, device, options)."""
    out: dict[tuple, list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        device = r["machine"].get("device", "cpu")
        out[(r["steps"], task_of(r), algo_of(r), r["toolkit"], device, tuple(r["options"]))].append(r)
    return out


# --- the tables ----------------------------------------------------------------------------------------


HEADER = (
    "| task | algorithm | toolkit | seeds | training R / C at 1M | at 2M | published at 1M | at 2M "
    "| eval, sampled R / C (cost's 95% bound) | eval, mean action | CPU-s per 1M steps | note |"
)


def table(steps: int, grouped: dict[tuple, list[dict[str, Any]]], cache: dict) -> list[str]:
    rows = [HEADER, "|" + "---|" * 12]
    for (s, task, algo, toolkit, device, options), recs in sorted(grouped.items()):
        if s != steps:
            continue
        marks = [curve_at(r, m) for r in recs for m in (1_000_000,)]
        marks2 = [curve_at(r, 2_000_000) for r in recs]
        pub = [published.at_steps(task, algo, m) for m in (1_000_000, 2_000_000)]
        notes = sorted({f"stale: options of {d}" for r in recs if (d := stale_since(r, cache))})
        if device != "cpu":
            notes.append(f"device {device}")
        if options:
            notes.append("options: " + " ".join(options))
        rows.append(
            f"| {task} | {algo} | {toolkit} | {len(recs)} "
            f"| {pair([m.get('episode_return') for m in marks], [m.get('episode_cost') for m in marks])} "
            f"| {pair([m.get('episode_return') for m in marks2], [m.get('episode_cost') for m in marks2])} "
            f"| {_published(pub[0])} | {_published(pub[1])} "
            f"| {eval_cell(recs, 'sampled')} | {eval_cell(recs, 'mean_action')} "
            f"| {cpu_per_million(recs)} | {'; '.join(notes)} |"
        )
    return rows


def _published(entry: tuple[str, str, float, float] | None) -> str:
    return "–" if entry is None else f"{entry[2]:.1f} / {entry[3]:.0f} ({entry[0]})"


def one_e7_table(grouped: dict[tuple, list[dict[str, Any]]]) -> list[str]:
    rows = [
        "| task | algorithm | ours: eval sampled R / C | ours: training R / C at 1e7 | OmniSafe 1e7 R / C (5 seeds) |"
    ]
    rows.append("|---|---|---|---|---|")
    for (s, task, algo, toolkit, device, options), recs in sorted(grouped.items()):
        if s != ONE_E7_STEPS or toolkit != "cmdp_rl":
            continue
        end = [curve_at(r, s) for r in recs]
        theirs = published.ONE_E7.get(task, {}).get(algo)
        ref = "–" if theirs is None else f"{theirs[1]:.2f} ± {theirs[2]:.2f} / {theirs[3]:.2f} ± {theirs[4]:.2f}"
        rows.append(
            f"| {task} | {algo} ({len(recs)} seeds) | {eval_cell(recs, 'sampled')} "
            f"| {pair([e.get('episode_return') for e in end], [e.get('episode_cost') for e in end])} | {ref} |"
        )
    for task, others in sorted(published.ONE_E7_OTHERS.items()):
        for name, r, rs, c, cs in others:
            rows.append(f"| {task} | ({name}, OmniSafe only) | – | – | {r:.2f} ± {rs:.2f} / {c:.2f} ± {cs:.2f} |")
    return rows


def table_order(step_counts: Iterable[int]) -> list[int]:
    """The step counts with a table of their own, the headline's first and then in increasing order (1e7 has its own
    table beside OmniSafe's)."""
    return sorted((s for s in step_counts if s != ONE_E7_STEPS), key=lambda s: (s != HEADLINE_STEPS, s))


def report_lines(campaigns: Sequence[Campaign], records: Sequence[dict[str, Any]]) -> list[str]:
    grouped, cache = groups(records), {}
    total = sum(len(c.runs) for c in campaigns)
    dates = sorted(r["date"] for r in records)
    span = f"{dates[0]} to {dates[-1]}" if dates else "none yet"
    machines = sorted({r["machine"]["cpu"] for r in records})
    lines = [
        BEGIN,
        "",
        f"Records: {len(records)} of the {total} runs of the campaigns {', '.join(c.name for c in campaigns)} "
        f"(`experiments/benchmarks/campaigns/`), made {span} on {', '.join(machines) or '–'}. "
        f"Budget d = {BUDGET:g}. R / C: episode return / episode cost; each cell is the mean over the seeds "
        "± their standard deviation. Training figures are the last 100 training episodes of the sampled policy "
        "at that step (what the published curves show); the evaluation is the deployed policy on 50 fresh "
        "episodes per seed, the cost's 95% bound the largest seed's. Published values: `lab/bench/published.py` "
        "(OmniSafe's and FSRL's curves read at 1M and 2M; their 1e7 table).",
        "",
    ]
    for steps in table_order({k[0] for k in grouped}):
        lines += [f"**{steps / 1e6:g}M steps**", "", *table(steps, grouped, cache), ""]
    if any(k[0] == ONE_E7_STEPS for k in grouped):
        lines += ["**1e7 steps**", "", *one_e7_table(grouped), ""]
    if records:
        lines += [f"![training curves beside the published ones](figures/{FIGURE.name})", ""]
    return [*lines, END]


def write_report(campaigns: Sequence[Campaign], page: Path = PAGE, figure: Path = FIGURE) -> list[Path]:
    """Rewrite ``page``'s campaign section (between :data:`BEGIN` and :data:`END`, or at its top) and ``figure``."""
    records = read_records(campaigns)
    block = "\n".join(report_lines(campaigns, records)) + "\n"
    text = page.read_text() if page.is_file() else ""
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        text = head + block.rstrip("\n") + rest.split(END, 1)[1]
    else:  # the top of the page: after its title
        title, _, body = text.partition("\n")
        text = f"{title}\n\n{block}{body}"
    page.write_text(text)
    written = [page]
    if records:
        plot_curves(records, figure)
        written.append(figure)
    return written


def plot_curves(records: Sequence[dict[str, Any]], path: Path) -> None:
    """Per task, the training return and cost against steps (mean over seeds) of each (algorithm, toolkit), the
    published 1M and 2M values as crosses in the same colour, the budget as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by_task: dict[str, dict[tuple, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        if r["machine"].get("device", "cpu") == "cpu":
            by_task[task_of(r)][(algo_of(r), r["toolkit"], r["steps"])].append(r)
    tasks = sorted(by_task)
    fig, axes = plt.subplots(2, len(tasks), figsize=(5 * len(tasks), 7), squeeze=False)
    colours = plt.get_cmap("tab10")
    for j, task in enumerate(tasks):
        algos = sorted({a for a, _, _ in by_task[task]})
        for (algo, toolkit, steps), recs in sorted(by_task[task].items()):
            colour = colours(algos.index(algo) % 10)
            style = "-" if toolkit == "cmdp_rl" else "--"
            marks = sorted({p["step"] for r in recs for p in r["curve"]})
            for i, key in enumerate(("episode_return", "episode_cost")):
                ys = [_mean([curve_at(r, m).get(key) for r in recs]) for m in marks]
                label = f"{algo} ({toolkit}, {steps / 1e6:g}M, {len(recs)} seeds)"
                axes[i][j].plot([m / 1e6 for m in marks], ys, style, color=colour, label=label)
        for algo in algos:
            for m in (1_000_000, 2_000_000):
                pub = published.at_steps(task, algo, m)
                if pub:
                    for i in (0, 1):
                        axes[i][j].plot(m / 1e6, pub[2 + i], "x", color=colours(algos.index(algo) % 10), ms=9)
        axes[0][j].set_title(task)
        axes[1][j].axhline(BUDGET, color="black", lw=0.8)
        axes[1][j].set_xlabel("env steps (millions)")
        axes[0][j].legend(fontsize=6)
    axes[0][0].set_ylabel("training return (last 100 episodes)")
    axes[1][0].set_ylabel("training cost (x: published)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90, metadata={"Software": None})  # no version or date: the same records, the same bytes
    plt.close(fig)


def _mean(values: Sequence[Any]) -> float:
    values = [v for v in values if v is not None]
    return statistics.fmean(values) if values else float("nan")
