"""Penalty versus constraint on Reach1D (the seed's second exercise), from a sweep's outputs.

The command line over :mod:`lab.studies.penalty_vs_constraint`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.studies.penalty_vs_constraint import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
