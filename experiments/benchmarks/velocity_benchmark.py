"""The velocity benchmark: ppo, ppo_lag and cpo on HalfCheetah with budget 25, 3 seeds; a table and a PNG.

The command line over :mod:`lab.bench.velocity_benchmark`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.velocity_benchmark import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
