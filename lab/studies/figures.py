"""The penalty-versus-constraint figure, and the way it draws a few seeds.

Left panel: episode cost against the fixed penalty λ (penalty runs, one colour per start
distribution) with the reference's predicted cost as a dashed step function and each budget d a
dotted line. Then one panel per start distribution: cost against the budget d (constrained runs,
one colour per algorithm), the diagonal cost = d the ideal. Each seed is a small dot, the mean
over seeds a large one (with 3 seeds a std bar would mislead); series at the same x are shifted
side by side rather than drawn on top of each other.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from cmdp_rl.report.plot import pyplot, save_figure
from cmdp_rl.report.sweeps import OK
from lab.studies.penalty_constraint import Reference, Run


def dodge(i: int, n: int, span: float) -> float:
    """The x shift of series ``i`` of ``n`` drawn at the same x values (1.5 % of ``span`` apart)."""
    return (i - (n - 1) / 2) * 0.015 * span


def seeds_and_means(
    ax: Any,
    xs: Sequence[float],
    ys: Sequence[float],
    means: Sequence[tuple[float, float]],
    x_shift: float,
    color: str,
    label: str,
    marker: str = "o",
) -> None:
    """Every seed's ``(x, y)`` as a small dot, the ``(x, mean)`` pairs as large markers (labelled)."""
    ax.plot([x + x_shift for x in xs], ys, ".", color=color, alpha=0.45, ms=5)
    if means:
        x, y = map(np.array, zip(*means))
        ax.plot(x + x_shift, y, marker, color=color, ms=7, label=label)


def _runs_series(
    ax: Any, mine: list[Run], means: list[tuple[float, float]], x_shift: float, color: str, label: str
) -> None:
    seeds_and_means(ax, [r.key.value for r in mine], [r.eval_cost for r in mine], means, x_shift, color, label)


def penalty_constraint_figure(
    path: Path, rows: list[dict[str, Any]], runs: list[Run], reference: Reference | None
) -> None:
    """Draw the figure (see the module docstring) from the table's ``rows`` and the ``runs``."""
    plt = pyplot()

    starts = sorted({r["start"] for r in rows})
    con_starts = sorted({r["start"] for r in rows if r["knob"] == "d"})
    fig, axes = plt.subplots(
        1, 1 + max(1, len(con_starts)), figsize=(5.6 * (1 + max(1, len(con_starts))), 4.8), squeeze=False
    )
    ax_p, con_axes = axes[0][0], axes[0][1:]
    done = [r for r in runs if r.status == OK and r.key is not None]
    budgets = sorted({r["value"] for r in rows if r["knob"] == "d"})
    lam_max = max([r["value"] for r in rows if r["knob"] == "lambda"] + [2.0]) * 1.1
    d_max = max(budgets + [1.0]) * 1.05

    # Penalty runs: one colour per start distribution, the reference's step function dashed.
    for i, s in enumerate(starts):
        shift = dodge(i, len(starts), lam_max)
        mine = [r for r in done if r.key.knob == "lambda" and r.key.start == s]
        means = sorted(
            (r["value"], r["cost_mean"]) for r in rows if r["knob"] == "lambda" and r["start"] == s and r["runs_ok"]
        )
        if mine:
            _runs_series(ax_p, mine, means, shift, f"C{i}", f"runs: mean (dots: seeds), {s}")
        if reference is not None and s in reference.starts:
            grid = np.linspace(0.0, lam_max, 600)
            ax_p.plot(
                grid,
                reference.cost_curve(s, grid),
                "--",
                color=f"C{i}",
                alpha=0.8,
                label=f"penalty-optimal plan (DP), {s}",
            )
    marker = reference.penalty_marker() if reference is not None else None
    if marker is not None:
        ax_p.axvline(marker[0], color="0.3", lw=0.8)
        ax_p.annotate(marker[1], (marker[0], 1.08), fontsize=8, ha="center")
    for d in budgets:
        ax_p.axhline(d, color="0.6", lw=0.8, ls=":")
        ax_p.annotate(f"d={d:g}", (lam_max, d), fontsize=7, color="0.4", ha="right", va="bottom")
    ax_p.set(
        xlabel="fixed penalty λ",
        ylabel="episode cost (crossings), final eval",
        ylim=(-0.05, 1.15),
        title="Penalty r − λc: cost against λ (dotted: budgets d)",
    )
    if not any(r.key.knob == "lambda" for r in done):
        ax_p.text(0.5, 0.5, "no finished penalty runs", transform=ax_p.transAxes, ha="center")
    if ax_p.get_legend_handles_labels()[0]:
        ax_p.legend(fontsize=7, loc="upper right", bbox_to_anchor=(1.0, 0.93))

    # Constrained runs: a panel per start distribution, one colour per algorithm.
    algos = sorted({r["algo"] for r in rows if r["knob"] == "d"})
    for ax, s in zip(con_axes, con_starts or ["(none)"]):
        ax.plot([0, d_max], [0, d_max], "k--", lw=1, label="ideal: cost = d")
        if reference is not None and s in reference.starts:
            cap = reference.unconstrained_cost(s)
            if cap < d_max:
                grid = np.linspace(0, d_max, 100)
                ax.plot(grid, np.minimum(grid, cap), "k:", lw=1, label="ideal, capped at the λ=0 cost")
        for j, algo in enumerate(algos):
            color = f"C{j + 2}"
            shift = dodge(j, len(algos), d_max)
            mine = [r for r in done if r.key.knob == "d" and r.key.start == s and r.key.algo == algo]
            mine_rows = [r for r in rows if r["knob"] == "d" and r["start"] == s and r["algo"] == algo and r["runs_ok"]]
            if mine:
                _runs_series(
                    ax,
                    mine,
                    sorted((r["value"], r["cost_mean"]) for r in mine_rows),
                    shift,
                    color,
                    f"{algo}: eval mean (dots: seeds)",
                )
                tc = sorted((r["value"], r["train_cost_mean"]) for r in mine_rows)
                ax.plot(
                    [v + shift for v, _ in tc],
                    [c for _, c in tc],
                    "x",
                    color=color,
                    ms=7,
                    label=f"{algo}: training cost, last 25%",
                )
        ax.set(
            xlabel="budget d (expected crossings per episode)",
            ylabel="episode cost (crossings)",
            title=f"Constraint J_c ≤ d, {s}",
        )
        if not any(r.key.knob == "d" and r.key.start == s for r in done):
            ax.text(0.5, 0.5, "no finished constrained runs", transform=ax.transAxes, ha="center")
        ax.legend(fontsize=7, loc="upper left")
    save_figure(fig, path, dpi=110)
