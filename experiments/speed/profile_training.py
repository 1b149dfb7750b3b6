"""Profile end-to-end training with cProfile on CPU time: where does a training step go?.

The command line over :mod:`lab.bench.profile_training`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.profile_training import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
