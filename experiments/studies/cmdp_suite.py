"""Algorithms on the generated suite of CMDPs (env=suite), each deployed policy judged exactly against
its instance's LP optimum; tuning and held-aside instances reported apart (docs/constraint_satisfaction.md).

The command line over :mod:`lab.studies.cmdp_suite` (its ``main``), where the code and the options'
documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl and lab

from lab.studies.cmdp_suite import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
