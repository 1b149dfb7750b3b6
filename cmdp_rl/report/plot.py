"""Learning curves of runs: ``python -m cmdp_rl.report.plot <run dirs...> [-o curves.png] [--smooth K]``.

Draws episode return, episode cost (with each config's budget d dashed) and the Lagrange multiplier (a cost
and a multiplier panel per constraint) against env steps from each run's ``metrics.csv``. Runs whose configs
differ only in ``seed`` are one curve, the mean with a band of one standard deviation, each run first smoothed
by a trailing mean over ``K`` iterations that skips those in which no episode ended."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from cmdp_rl.config.run_config import flatten_dict
from cmdp_rl.config.saved import CONFIG, METRICS, deploy_node, read_yaml
from cmdp_rl.report.metrics import read_metrics

PANELS = (
    ("episode_return", "episode return"),
    ("episode_cost", "episode cost"),
    ("lagrange_multiplier", "Lagrange multiplier λ"),
)


def panels(columns: Sequence[str]) -> list[tuple[str, str]]:
    """(column, title) of each panel for a run with these metrics.csv columns: return, costs, multipliers."""
    out = [PANELS[0]]
    for name, title in PANELS[1:]:
        if name in columns:
            out.append((name, title))
        else:
            out += [(c, f"{title}: {c.partition('/')[2]}") for c in columns if c.startswith(name + "/")]
    return out


IGNORED = ("seed", "resume", "total_steps", "log_interval", "checkpoint_every", "threads", "logger")


def _grouped_across(key: str) -> bool:
    """What a run deploys does not change its training curves: a plot groups across the deploy node too."""
    return key in IGNORED or key.startswith("deploy.")


def config_key(flat: dict[str, Any], skip: Callable[[str], bool]) -> str:
    """A group's key: the flat config but the fields ``skip`` names."""
    return json.dumps({k: v for k, v in flat.items() if not skip(k)}, sort_keys=True, default=str)


def varying(cfgs: Sequence[dict[str, Any]], skip: Callable[[str], bool]) -> list[str]:
    """The fields every one of ``cfgs`` has, but those ``skip`` names, whose values differ: a group's label."""
    shared = set.intersection(*(set(c) for c in cfgs)) if cfgs else set()
    return sorted(k for k in shared if not skip(k) and len({json.dumps(c[k], default=str) for c in cfgs}) > 1)


@dataclass
class Curve:
    """One group of runs: mean and band ``(low, high)`` per panel (none for one run), each cost panel's budget."""

    label: str
    step: np.ndarray
    mean: dict[str, np.ndarray]
    band: dict[str, tuple[np.ndarray, np.ndarray]]
    seeds: int
    cost_limits: dict[str, float]
    panels: list[tuple[str, str]]

    @property
    def cost_limit(self) -> float:
        """The first constraint's budget."""
        return next(iter(self.cost_limits.values()), float("nan"))


def read_run(run_dir: str | Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """``(flat config, columns)`` of one run."""
    run = Path(run_dir)
    if not (run / METRICS).is_file():
        raise FileNotFoundError(f"plot: no {METRICS} in {run}")
    cfg = flatten_dict(deploy_node(read_yaml(run / CONFIG, "plot"))) if (run / CONFIG).is_file() else {}
    rows = read_metrics(run / METRICS)
    if not rows:
        raise ValueError(f"plot: {run / METRICS} has no rows yet")
    cols = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    return cfg, cols


def smooth(x: np.ndarray, k: int) -> np.ndarray:
    """Trailing mean over the finite values in a window of ``k`` entries."""
    if k <= 1:
        return x
    out = np.full_like(x, np.nan)
    for i in range(len(x)):
        w = x[max(0, i - k + 1) : i + 1]
        w = w[np.isfinite(w)]
        if w.size:
            out[i] = w.mean()
    return out


def aggregate(runs: Sequence[dict[str, np.ndarray]], k: int = 1) -> tuple[np.ndarray, dict, dict]:
    """Mean and standard deviation across runs, per metric, over the iterations all runs reached."""
    n = min(len(r["step"]) for r in runs)
    step = runs[0]["step"][:n]
    mean, std = {}, {}
    for name, _ in panels(list(runs[0])):
        stack = np.stack([smooth(r.get(name, np.full(n, np.nan))[:n], k) for r in runs])
        with warnings.catch_warnings():  # an iteration where no run has a value stays NaN, quietly
            warnings.simplefilter("ignore", RuntimeWarning)
            mean[name], std[name] = np.nanmean(stack, axis=0), np.nanstd(stack, axis=0)
    return step, mean, std


def group_runs(run_dirs: Sequence[str | Path], k: int = 1) -> list[Curve]:
    """Group runs whose configs agree but for :data:`IGNORED` and the deploy node, and average each group."""
    groups: dict[str, list[tuple[dict, dict]]] = {}
    for cfg, cols in map(read_run, run_dirs):
        groups.setdefault(config_key(cfg, _grouped_across), []).append((cfg, cols))
    # Labels: the algorithm and what else tells the groups apart (its own options are implied by its name).
    labels = varying([m[0][0] for m in groups.values()], lambda k_: _grouped_across(k_) or k_ == "algo.name")
    curves = []
    for members in groups.values():
        cfg, cols = members[0]
        extra = ", ".join(f"{k_}={cfg.get(k_)}" for k_ in labels)
        label = cfg.get("algo.name", "run") + (f" ({extra})" if extra else "")
        step, mean, std = aggregate([c for _, c in members], k)
        band = {n: (mean[n] - std[n], mean[n] + std[n]) for n in mean} if len(members) > 1 else {}
        given = cfg.get("algo.cost_limit", np.nan)
        given = np.array([np.nan if isinstance(given, list) else given])
        shown = panels(list(cols))
        limits = {
            n: float(cols.get("cost_limit" + n.removeprefix("episode_cost"), given)[0])
            for n, _ in shown
            if n.startswith("episode_cost")
        }
        seeds = f"{len(members)} seed{'s' if len(members) > 1 else ''}"
        curves.append(Curve(f"{label}, {seeds}", step, mean, band, len(members), limits, shown))
    return curves


def plot_runs(run_dirs: Sequence[str | Path], out: str | Path, k: int = 5) -> Path:
    """Draw :data:`PANELS` for the runs in ``run_dirs`` into the PNG ``out``."""
    curves = group_runs(run_dirs, k)
    band = "mean ± 1 std over seeds" if any(c.seeds > 1 for c in curves) else "one seed per curve"
    return draw(curves, out, f"{band}; trailing mean over {k} iterations")


def draw(curves: Sequence[Curve], out: str | Path, title: str) -> Path:
    """Each curve's panels (every curve's, in order of first appearance), its band and budgets, into ``out``."""
    plt = pyplot()
    shown = list(dict.fromkeys(p for c in curves for p in c.panels)) or list(PANELS[:2])
    fig, axes = plt.subplots(1, len(shown), figsize=(5 * len(shown), 3.8), squeeze=False)
    axes = axes[0]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    limits_drawn: set[tuple[str, float]] = set()
    for i, c in enumerate(curves):
        color = colors[i % len(colors)]
        for ax, (name, _) in zip(axes, shown):
            if name not in c.mean:
                continue
            ax.plot(c.step, c.mean[name], color=color, lw=1.6, label=c.label)
            if name in c.band:
                ax.fill_between(c.step, *c.band[name], color=color, alpha=0.2, lw=0)
            limit = c.cost_limits.get(name, np.nan)
            if np.isfinite(limit) and (name, limit) not in limits_drawn:
                limits_drawn.add((name, limit))
                ax.axhline(limit, color="black", ls="--", lw=1, label=f"budget d = {limit:g}")
    for ax, (_, title) in zip(axes, shown):
        ax.set_title(title)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    axes[min(1, len(shown) - 1)].legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=9)
    return save_figure(fig, out)


def pyplot() -> Any:
    """matplotlib's pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: str | Path, dpi: int = 100) -> Path:
    """Lay out ``fig``, write it to ``path`` (making its folder) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m cmdp_rl.report.plot",
        description=__doc__.split("\n\n")[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("runs", nargs="+", help="run directories (each with metrics.csv and config.yaml)")
    parser.add_argument("-o", "--out", default="curves.png", help="PNG to write (default: curves.png)")
    parser.add_argument("--smooth", type=int, default=5, help="trailing mean over SMOOTH iterations (default 5)")
    args = parser.parse_args(argv)
    if args.smooth < 1:
        parser.error(f"--smooth must be a positive integer, got {args.smooth}")
    try:
        path = plot_runs(args.runs, args.out, args.smooth)
    except (FileNotFoundError, ValueError) as exc:  # ValueError: ConfigError too (a config.yaml not valid YAML)
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
