"""A benchmark campaign: a resumable queue of training runs and the records they leave (docs/benchmarks.md).

The command line over :mod:`lab.bench.campaign`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.campaign import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
