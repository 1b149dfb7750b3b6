"""env=safe_nav against its physics bound: where ppo_lag training's time goes, per task, in one run.

The command line over :mod:`lab.bench.safe_nav_profile`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.safe_nav_profile import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
