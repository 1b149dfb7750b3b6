"""Penalty versus constraint on Reach1D (the seed's second exercise), from a sweep's outputs.

    python experiments/studies/penalty_vs_constraint.py multirun/penalty_vs_constraint/<time> [...] [--out DIR]
    python experiments/studies/penalty_vs_constraint.py --population DIR [--skip-unbatched] [--compare TABLE.md] [override ...]

Reads every run directory under the given sweep directories (``make sweep`` writes them; nothing
is re-trained) and writes, into ``--out`` (default ``<first dir>/report``):

- ``table.md`` / ``table.csv``: per algorithm, lambda or budget d, and start distribution: runs
  finished out of expected, mean and spread (std over seeds) of the final evaluation's episode
  return and cost, the training episode cost over the last quarter of iterations, the final lambda,
  and what the analysis predicts;
- ``runs.csv``: every run (and every job the sweeps' multirun.yaml expected but that left nothing)
  with its status: ok, failed (error.txt says why), incomplete (started, no result: killed, or
  its joblib pool was broken by another job's hard crash), missing (never started), superseded
  (the same job ran again: the rerun is used);
- ``rerun.sh``: one command per job that did not finish, running it again into
  ``<its sweep>/rerun``;
- ``penalty_vs_constraint.png``: episode cost against lambda for the penalty runs, each budget d a
  horizontal line, the penalty-optimal step function from the analysis; achieved cost against d
  for the constrained runs, the diagonal the ideal;
- ``answers.md``: the exercise's answers computed from the env's parameters
  (``lab.studies.reach1d_thresholds``) and checked against the runs.

``--population DIR`` first trains the whole grid of both sweeps in this process, as populations
(``cmdp_rl.population``: one population per algorithm, on ``env.backend=torch``; cpo's agents take
their policy steps one after another; ``--skip-unbatched`` leaves out a part whose agents would
train one after another, none in the grid as configured), into
``DIR/{penalty,constraint}/<algo>/``, then reports on ``DIR`` as above; ``DIR/timing.json`` holds
each part's wall time. Overrides apply to every job (e.g. ``total_steps=204800``). ``--compare``
reads another report's ``table.md`` (e.g. docs/penalty_vs_constraint.md, separate runs) and counts
the rows whose eval return and cost agree within the seeds' spread.

The pieces live in ``lab.studies``: ``penalty_constraint`` (grouping, table, status, rerun
script), ``reach1d_reference`` (the exact reference and the answers) and ``figures``; a study of
the same kind on another env needs only its own reference.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from cmdp_rl.report.sweeps import MISSING, SUPERSEDED
from lab.studies.figures import penalty_constraint_figure
from lab.studies.penalty_constraint import (
    gather,
    rerun_script,
    status_rows,
    table_markdown,
    table_rows,
    unfinished,
)
from lab.studies.reach1d_reference import answers_markdown, reach1d_reference
from lab.studies.tables import write_csv

SHOW_NOT_OK = 20  # runs that did not finish listed on the console (all of them in runs.csv)


def report(dirs: list[Path], out: Path) -> dict[str, Any]:
    """Gather, analyse, write every output; returns what was written and the run counts."""
    runs, records = gather(dirs)
    reference = reach1d_reference(records)
    rows = table_rows(runs, reference)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(table_markdown(rows))
    write_csv(out / "table.csv", rows)
    write_csv(out / "runs.csv", status_rows(runs))
    (out / "answers.md").write_text(answers_markdown(reference, rows))
    (out / "rerun.sh").write_text(rerun_script(runs))
    penalty_constraint_figure(out / "penalty_vs_constraint.png", rows, runs, reference)
    counts: dict[str, int] = defaultdict(int)
    for r in runs:
        counts[r.status] += 1
    return {"rows": rows, "runs": runs, "counts": dict(counts), "out": out}


def train_grid(out: Path, overrides: list[str], skip_unbatched: bool) -> dict[str, float]:
    """Both sweeps' grids in this process, one population per algorithm. Returns each part's wall
    time in seconds (and the total wall and CPU time)."""
    import time

    from cmdp_rl.population import population
    from cmdp_rl.run.trainer import train
    from lab.studies.population_sweep import sweep_parts

    timing: dict[str, float] = {}
    start, cpu = time.perf_counter(), time.process_time()
    for experiment, sub in (("penalty_sweep", "penalty"), ("constraint_sweep", "constraint")):
        for part in sweep_parts(experiment):
            if skip_unbatched and not part.batched:
                continue
            t0 = time.perf_counter()
            raw = _composed(part.overrides(experiment, ["env.backend=torch", *overrides]))
            train(population(raw), out / sub / part.name, echo=print if part.batched else _agents_only)
            timing[f"{sub}/{part.name}"] = time.perf_counter() - t0
            print(f"{sub}/{part.name}: {timing[f'{sub}/{part.name}']:.1f} s")
    timing["total"] = time.perf_counter() - start
    timing["total_cpu"] = time.process_time() - cpu  # this process's CPU seconds: what a free core would need
    return timing


def _agents_only(line: str) -> None:
    """An unbatched population's echo, its agents' own lines left out (one line per agent)."""
    if line.startswith(("agent ", "population: ", "done: ")) and (" steps in " not in line or " summed)" in line):
        print(line)


def _composed(overrides: list[str]) -> dict[str, Any]:
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from cmdp_rl.config.run_config import CONFIG_DIR

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return OmegaConf.to_container(compose("config", overrides=overrides), resolve=True)


def compare(rows: list[dict[str, Any]], table_md: Path) -> dict[str, Any]:
    """Rows of this report against another report's markdown table: per row, whether the eval
    return's and cost's means agree within the seeds' spread: a difference of at most twice its
    standard error over the seeds, ``2 sqrt((s1^2 + s2^2) / n)`` (n = 3 seeds per row), and at
    least 0.05 (three seeds that agree exactly show no spread)."""
    other: dict[tuple, tuple] = {}
    for line in table_md.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 6 and "±" in cells[4]:
            other[(cells[0], cells[1], cells[2])] = tuple(tuple(float(x) for x in c.split("±")) for c in cells[4:6])
    agree, total, differ = 0, 0, []
    for line in table_markdown(rows).splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        key = (cells[0], cells[1], cells[2]) if len(cells) >= 6 else None
        if key not in other or "±" not in cells[4]:
            continue
        mine = [tuple(float(x) for x in c.split("±")) for c in cells[4:6]]
        n = int(cells[3].split("/")[0]) or 1
        ok = all(
            abs(m[0] - o[0]) <= max(2 * ((m[1] ** 2 + o[1] ** 2) / n) ** 0.5, 0.05) for m, o in zip(mine, other[key])
        )
        total += 1
        agree += ok
        if not ok:
            differ.append(
                f"{' '.join(key)}: return {cells[4]} vs {other[key][0][0]:.3f} ± {other[key][0][1]:.3f}, "
                f"cost {cells[5]} vs {other[key][1][0]:.3f} ± {other[key][1][1]:.3f}"
            )
    return {"rows": total, "agree": agree, "differ": differ}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dirs", nargs="*", type=Path, help="sweep directories (searched recursively)")
    parser.add_argument("--out", type=Path, default=None, help="where to write (default: <first dir>/report)")
    parser.add_argument(
        "--population",
        type=Path,
        default=None,
        help="train the whole grid into this directory as populations first, then report on it",
    )
    parser.add_argument(
        "--skip-unbatched", action="store_true", help="with --population: leave out the parts that are not batched"
    )
    parser.add_argument("--compare", type=Path, default=None, help="another report's table.md to compare with")
    args = parser.parse_args(argv)
    overrides = [str(d) for d in args.dirs if "=" in str(d)]  # key=value: overrides for --population's jobs
    args.dirs = [d for d in args.dirs if "=" not in str(d)]
    if args.population is not None:
        timing = train_grid(args.population, overrides, args.skip_unbatched)
        args.population.mkdir(parents=True, exist_ok=True)
        (args.population / "timing.json").write_text(json.dumps({**timing, "load": os.getloadavg()}, indent=2))
        args.dirs = [args.population, *args.dirs]
    if not args.dirs:
        parser.error("give sweep directories, or --population DIR")
    for d in args.dirs:
        if not d.is_dir():
            print(f"not a directory: {d}", file=sys.stderr)
            return 2
    out = args.out or args.dirs[0] / "report"
    result = report(args.dirs, out)
    print(table_markdown(result["rows"]))
    counts = result["counts"]
    print(
        "runs: "
        + ", ".join(f"{counts.get(s, 0)} {s}" for s in ("ok", "failed", "incomplete", "missing"))
        + (f" ({counts[SUPERSEDED]} superseded by reruns)" if counts.get(SUPERSEDED) else "")
    )
    not_ok = unfinished(result["runs"])
    for r in not_ok[:SHOW_NOT_OK]:
        where = r.path if r.status != MISSING else f"{r.path}: {' '.join(r.overrides)}"
        print(f"  {r.status}: {where}" + (f" ({r.error})" if r.error else ""))
    if len(not_ok) > SHOW_NOT_OK:
        print(f"  ... and {len(not_ok) - SHOW_NOT_OK} more: see {out}/runs.csv")
    if not_ok:
        print(f"to run them again: sh {out}/rerun.sh")
    print(f"wrote {out}/table.md, table.csv, runs.csv, answers.md, rerun.sh, penalty_vs_constraint.png")
    if args.compare is not None:
        result = compare(result["rows"], args.compare)
        print(f"against {args.compare}: {result['agree']} of {result['rows']} rows agree within the seeds' spread")
        for line in result["differ"]:
            print(f"  differs: {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
