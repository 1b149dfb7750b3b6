"""Size and save time of a checkpoint that holds a replay buffer (sac_lag on HalfCheetah velocity).

    python experiments/speed/checkpoint_cost.py [--transitions 100032] [--updates 8] [--repeats 15] [--out DIR]

The command line over :mod:`lab.bench.checkpoint_cost`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.checkpoint_cost import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
