"""The off-policy benchmark: sac_lag and ppo_lag on HalfCheetah velocity (d = 25), 3 seeds each, at.

The command line over :mod:`lab.bench.off_policy_benchmark`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.off_policy_benchmark import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
