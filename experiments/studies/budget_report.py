"""How well does each algorithm of a sweep keep to its budget, during training and after?.

The command line over :mod:`lab.studies.budget_report`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.studies.budget_report import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
