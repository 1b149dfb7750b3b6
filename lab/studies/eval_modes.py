"""Both evaluation modes of finished runs side by side (docs/evaluation.md, "Which mode"): per run the deployed
policy's return, mean cost and worst episode cost with sampled actions and with the mean action (eval.json's
``modes``), and how often the mean action's worst episode is the worse one, or passes 200.

    python -m lab.studies.eval_modes outputs/exp/*/        # any run directories
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

PARKED = 200.0  # an episode cost above this: the policy sat in a hazard for a fifth of a 1000-step episode


def rows(run_dirs: list[Path]) -> list[tuple]:
    out = []
    for run in run_dirs:
        path = run / "eval.json"
        modes = json.loads(path.read_text()).get("modes") if path.is_file() else None
        if modes:
            s, m = modes["sampled"], modes["mean_action"]
            out.append(
                (run.name, *(x[k] for k in ("episode_return", "episode_cost", "episode_cost_max") for x in (s, m)))
            )
    return out


def main(argv: list[str] | None = None) -> int:
    table = rows([Path(p) for p in (argv if argv is not None else sys.argv[1:])])
    print("| run | return, sampled / mean action | cost | worst episode |\n|---|---|---|---|")
    for name, rs, rm, cs, cm, ws, wm in table:
        print(f"| {name} | {rs:.1f} / {rm:.1f} | {cs:.1f} / {cm:.1f} | {ws:.0f} / {wm:.0f} |")
    n = len(table)
    print(
        f"{n} runs: the mean action's worst episode is the worse in {sum(r[6] > r[5] for r in table)}, its mean cost "
        f"the higher in {sum(r[4] > r[3] for r in table)}; worst episode over {PARKED:.0f}: mean action "
        f"{sum(r[6] > PARKED for r in table)}, sampled {sum(r[5] > PARKED for r in table)}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
