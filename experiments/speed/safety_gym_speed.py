"""Env steps per second on a Safety-Gymnasium task: the package's own loop against our collector,.

The command line over :mod:`lab.bench.safety_gym_speed`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.safety_gym_speed import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
