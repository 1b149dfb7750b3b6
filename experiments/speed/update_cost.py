"""What one PPO update costs as its minibatches grow: is the update bound by per-op overhead or by.

The command line over :mod:`lab.bench.update_cost`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.update_cost import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
