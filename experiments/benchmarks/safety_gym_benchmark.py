"""The Safety-Gymnasium benchmark: ppo, ppo_lag, pid_lag and cpo on SafetyPointGoal1-v0 and.

The command line over :mod:`lab.bench.safety_gym_benchmark`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.safety_gym_benchmark import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
