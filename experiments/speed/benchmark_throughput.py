"""Throughput of the toolkit on Reach1D: env, rollout and end-to-end training steps per second.

The command line over :mod:`lab.bench.benchmark_throughput`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.benchmark_throughput import main  # noqa: E402

if __name__ == "__main__":
    main()  # returns the figures it wrote, for a caller in Python
