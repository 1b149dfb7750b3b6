"""Constraint satisfaction of the Lagrangian methods' final policies on CMDPs with exact optima
(docs/constraint_satisfaction.md).

The command line over :mod:`lab.studies.constraint_satisfaction` (its ``main``), where the code
and the options' documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.studies.constraint_satisfaction import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
