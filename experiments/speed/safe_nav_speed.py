"""env=safe_nav against the reference (env=safety_gym): env steps/s and ppo_lag training steps/s,.

The command line over :mod:`lab.bench.safe_nav_speed`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.safe_nav_speed import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
