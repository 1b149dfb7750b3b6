"""Penalty versus constraint on Reach1D (the seed's second exercise), from a sweep's outputs.

    python experiments/penalty_vs_constraint.py multirun/penalty_vs_constraint/<time> [...] [--out DIR]

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
  (``cmdp_rl.envs.reach1d_dp``) and checked against the runs.

The pieces live in ``cmdp_rl.analysis``: ``penalty_constraint`` (grouping, table, status, rerun
script), ``reach1d_reference`` (the exact reference and the answers) and ``figures``; a study of
the same kind on another env needs only its own reference.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from cmdp_rl.analysis.figures import penalty_constraint_figure
from cmdp_rl.analysis.penalty_constraint import (
    gather, rerun_script, status_rows, table_markdown, table_rows, unfinished,
)
from cmdp_rl.analysis.reach1d_reference import answers_markdown, reach1d_reference
from cmdp_rl.analysis.tables import write_csv
from cmdp_rl.sweeps import MISSING, SUPERSEDED

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dirs", nargs="+", type=Path, help="sweep directories (searched recursively)")
    parser.add_argument("--out", type=Path, default=None, help="where to write (default: <first dir>/report)")
    args = parser.parse_args(argv)
    for d in args.dirs:
        if not d.is_dir():
            print(f"not a directory: {d}", file=sys.stderr)
            return 2
    out = args.out or args.dirs[0] / "report"
    result = report(args.dirs, out)
    print(table_markdown(result["rows"]))
    counts = result["counts"]
    print("runs: " + ", ".join(f"{counts.get(s, 0)} {s}" for s in ("ok", "failed", "incomplete", "missing"))
          + (f" ({counts[SUPERSEDED]} superseded by reruns)" if counts.get(SUPERSEDED) else ""))
    not_ok = unfinished(result["runs"])
    for r in not_ok[:SHOW_NOT_OK]:
        where = r.path if r.status != MISSING else f"{r.path}: {' '.join(r.overrides)}"
        print(f"  {r.status}: {where}" + (f" ({r.error})" if r.error else ""))
    if len(not_ok) > SHOW_NOT_OK:
        print(f"  ... and {len(not_ok) - SHOW_NOT_OK} more: see {out}/runs.csv")
    if not_ok:
        print(f"to run them again: sh {out}/rerun.sh")
    print(f"wrote {out}/table.md, table.csv, runs.csv, answers.md, rerun.sh, penalty_vs_constraint.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
