"""Where a navigation step's time goes in our pipeline: cProfile over one collector rollout of a.

The command line over :mod:`lab.bench.safety_gym_profile`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.safety_gym_profile import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
