"""The search's report (docs/tuning.md): the best options within budget, their return and costs with intervals, the
command that reruns them, ``tune.json`` and Optuna's plots in the sweep directory. The search writes it when it ends;
``python -m cmdp_rl.tune.report <storage> [--study NAME] [--out DIR]`` writes it again from the storage (a URL, or
the path of the SQLite file), while the search runs or after."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import warnings
from pathlib import Path
from typing import Any, Sequence

from cmdp_rl.tune.trial import best_feasible, feasible


def _ci(pair: Sequence[float], fmt: str) -> str:
    return f"95% CI [{pair[0]:{fmt}}, {pair[1]:{fmt}}]"


def trial_line(trial: Any, budget: Sequence[float]) -> str:
    """One finished trial: its return and costs against the budgets, and the verdict."""
    a = trial.user_attrs
    costs = ", ".join(f"{c:.3g} (upper {u:.3g}, budget {d:g})" for c, u, d in zip(a["cost"], a["cost_upper"], budget))
    verdict = "within budget" if feasible(trial) else "over budget"
    return f"trial {trial.number}: return {a['return']:.4g}, {_ci(a['return_ci'], '.4g')}; cost {costs}: {verdict}"


def rerun(trial: Any, seed: int | None = None) -> str:
    """The command that trains the trial's options again: its own seeds, or ``seed`` and the ones after it."""
    args = list(trial.user_attrs["overrides"])
    if seed is not None:
        args = [a for a in args if not a.startswith("seed=")] + [f"seed={seed}"]
    return "python train.py " + " ".join(shlex.quote(a) for a in args)


def report(study: Any, out_dir: str | Path, plots: bool = True) -> str:
    """The report's text; ``tune.json`` and (``plots``) the PNGs written to ``out_dir``."""
    from optuna.trial import TrialState

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    attrs = study.user_attrs
    budget, names, seeds = attrs["budget"], attrs["cost_names"], attrs["seeds"]
    trials = study.get_trials(deepcopy=False)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    pruned = [t for t in trials if t.state == TrialState.PRUNED]
    failed = [t for t in trials if t.state == TrialState.FAIL]
    ok = [t for t in complete if feasible(t)]
    best = best_feasible(trials)
    rule = "each cost's 95% upper bound" if attrs["feasible_by"] == "upper" else "each cost's mean"
    lines = [
        f"study {study.study_name!r}: {len(complete) + len(pruned)} trials finished ({len(complete)} complete, "
        f"{len(pruned)} pruned), {len(failed)} failed; {len(ok)} of {len(complete)} within budget "
        f"({rule} over seeds {', '.join(map(str, seeds))} at most its budget)"
    ]
    if best is None:
        lines.append("no trial is within budget: none is reported as best")
        if complete:
            near = min(complete, key=lambda t: sum(max(0.0, c) for c in t.user_attrs["constraint"]))
            lines.append(f"  the nearest: {trial_line(near, budget)}")
    else:
        a = best.user_attrs
        lines += [
            f"best within budget: trial {best.number}",
            "  options: " + " ".join(f"{k}={v}" for k, v in best.params.items()),
            f"  return {a['return']:.4g}, {_ci(a['return_ci'], '.4g')} (mean over {len(seeds)} seeds)",
        ]
        for name, c, ci, u, d in zip(names, a["cost"], a["cost_ci"], a["cost_upper"], budget):
            label = "cost" if len(names) == 1 else f"cost {name}"
            lines.append(f"  {label} {c:.3g}, {_ci(ci, '.3g')}, 95% upper bound {u:.3g}, budget {d:g}: within")
        lines += [f"  rerun:        {rerun(best)}", f"  on new seeds: {rerun(best, seeds[-1] + 1)}"]
    summary = {
        "study": study.study_name,
        "budget": dict(zip(names, budget)),
        "feasible_by": attrs["feasible_by"],
        "seeds": seeds,
        "finished": len(complete) + len(pruned),
        "complete": len(complete),
        "pruned": len(pruned),
        "failed": len(failed),
        "within_budget": len(ok),
        "best": None if best is None else {"trial": best.number, "params": best.params, **_kept(best)},
        "rerun": None if best is None else rerun(best),
        "trials": [
            {"trial": t.number, "state": t.state.name, "within_budget": feasible(t), "params": t.params, **_kept(t)}
            for t in trials
        ],
    }
    (out / "tune.json").write_text(json.dumps(summary, indent=2))
    if plots:
        lines.append("plots: " + ", ".join(str(out / p) for p in write_plots(study, out, best, lines)))
    return "\n".join(lines)


def _kept(trial: Any) -> dict[str, Any]:
    keys = ("return", "return_ci", "returns", "cost", "cost_ci", "cost_upper", "costs", "constraint", "error")
    return {k: trial.user_attrs[k] for k in keys if k in trial.user_attrs}


def write_plots(study: Any, out: Path, best: Any, notes: list[str]) -> list[str]:
    """Optuna's optimisation history and parameter importances, and the return-cost plane with the budgets (Optuna's
    Pareto-front plot is for multi-objective studies and draws no budget). A plot the study cannot have yet (too few
    trials) is left out, with a line saying why."""
    from cmdp_rl.report.plot import pyplot, save_figure

    pyplot()  # the file-only backend, before Optuna's plots import pyplot
    import optuna.visualization.matplotlib as ovm
    from optuna.importance import PedAnovaImportanceEvaluator

    written = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the matplotlib backend is marked experimental in every Optuna 4
        for name, draw in (
            ("history", lambda: ovm.plot_optimization_history(study, target_name="deployed eval return")),
            # PED-ANOVA: Optuna's importance evaluator that needs no scikit-learn (fANOVA, its default, does).
            ("importances", lambda: ovm.plot_param_importances(study, evaluator=PedAnovaImportanceEvaluator())),
            ("front", lambda: _front(study, best)),
        ):
            try:
                ax = draw()
            except (ValueError, RuntimeError, ZeroDivisionError) as exc:
                notes.append(f"no {name} plot: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
                continue
            save_figure(ax.figure if hasattr(ax, "figure") else ax.flat[0].figure, out / f"{name}.png", dpi=110)
            written.append(f"{name}.png")
    return written


def _front(study: Any, best: Any) -> Any:
    import matplotlib.pyplot as plt
    from optuna.trial import TrialState

    attrs = study.user_attrs
    names, budget = attrs["cost_names"], attrs["budget"]
    done = [t for t in study.get_trials(deepcopy=False) if t.state == TrialState.COMPLETE]
    if not done:
        raise ValueError("no complete trial")
    fig, axes = plt.subplots(1, len(names), figsize=(5.5 * len(names), 4.2), squeeze=False)
    for k, (ax, name) in enumerate(zip(axes[0], names)):
        for ok, color, label in ((True, "tab:blue", "within budget"), (False, "tab:red", "over budget")):
            pts = [t for t in done if feasible(t) == ok]
            if not pts:
                continue
            x = [t.user_attrs["cost"][k] for t in pts]
            y = [t.user_attrs["return"] for t in pts]
            # The cost's bar runs from its mean to its 95% upper bound, what the feasibility rule reads by default.
            xerr = [[0.0] * len(pts), [t.user_attrs["cost_upper"][k] - c for c, t in zip(x, pts)]]
            yerr = [[v - t.user_attrs["return_ci"][0] for v, t in zip(y, pts)]]
            yerr.append([t.user_attrs["return_ci"][1] - v for v, t in zip(y, pts)])
            ax.errorbar(x, y, xerr=xerr, yerr=yerr, fmt="o", color=color, alpha=0.7, ms=4, lw=0.8, label=label)
        # The front: for each cost, the best return of a trial no costlier (the non-dominated trials, as a step).
        front, top = [], float("-inf")
        for t in sorted(done, key=lambda t: (t.user_attrs["cost"][k], -t.user_attrs["return"])):
            if t.user_attrs["return"] > top:
                top = t.user_attrs["return"]
                front.append((t.user_attrs["cost"][k], top))
        right = max(max(t.user_attrs["cost_upper"][k] for t in done), budget[k]) * 1.05
        front.append((right, top))  # no costlier trial does better
        ax.step(*zip(*front), where="post", color="grey", lw=1, label="front")
        ax.axvline(budget[k], color="k", ls="--", lw=1, label=f"budget {budget[k]:g}")
        if best is not None:
            star = dict(color="gold", ms=16, mec="k", label=f"best (trial {best.number})")
            ax.plot(best.user_attrs["cost"][k], best.user_attrs["return"], "*", **star)
        ax.set_xlabel(f"eval cost{'' if len(names) == 1 else ' ' + name} (mean over seeds, to its 95% upper bound)")
        ax.set_ylabel("eval return (mean over seeds, 95% CI)")
        ax.legend(fontsize=8)
    axes[0][0].set_title(f"study {study.study_name!r}: return against cost", fontsize=10)
    return axes


def main(argv: list[str] | None = None) -> None:
    import optuna

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("storage", help="the study's storage: an Optuna RDB URL, or the path of its SQLite file")
    parser.add_argument("--study", help="the study's name (needed when the storage holds several)")
    parser.add_argument("--out", help="where tune.json and the plots go (default: beside the SQLite file, or .)")
    parser.add_argument("--no-plots", action="store_true")
    args = parser.parse_args(argv)
    path = Path(args.storage)
    url = args.storage if "://" in args.storage else f"sqlite:///{path.absolute()}"
    if "://" not in args.storage and not path.is_file():
        parser.exit(2, f"cmdp_rl.tune.report: no such file: {path}\n")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        names = optuna.get_all_study_names(url)
    except Exception as exc:  # noqa: BLE001 - SQLAlchemy's and the drivers' errors have no common base
        parser.exit(2, f"cmdp_rl.tune.report: cannot open storage {args.storage}: {str(exc).splitlines()[0]}\n")
    name = args.study or (names[0] if len(names) == 1 else None)
    if name not in names:
        parser.exit(2, f"cmdp_rl.tune.report: give --study, one of: {', '.join(names) or '(none)'}\n")
    out = Path(args.out) if args.out else (path.parent if "://" not in args.storage else Path("."))
    print(report(optuna.load_study(study_name=name, storage=url), out, plots=not args.no_plots))


if __name__ == "__main__":
    main(sys.argv[1:])
