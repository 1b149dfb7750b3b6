"""Steps per second on a velocity task: gymnasium's raw stepping against our collection and training.

The command line over :mod:`lab.bench.velocity_speed`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.velocity_speed import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
