"""Does Kp > 0 damp PID-Lagrangian's cost overshoot and oscillation? (Stooke, Achiam, Abbeel, 2020).

The command line over :mod:`lab.studies.pid_damping`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.studies.pid_damping import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
