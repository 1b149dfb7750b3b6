"""The algorithm table (docs/algorithms.md): every algorithm, 3 seeds, on three tasks.

The command line over :mod:`lab.bench.algorithm_table`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.algorithm_table import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
