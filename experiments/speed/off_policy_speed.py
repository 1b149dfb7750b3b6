"""CPU cost of an off-policy gradient step: sac_lag and td3_lag on HalfCheetah velocity with the.

The command line over :mod:`lab.bench.off_policy_speed`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.off_policy_speed import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
