"""Training throughput of two commits, measured in alternation so that both see the same load.

The command line over :mod:`lab.bench.speed_between_commits`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.speed_between_commits import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
