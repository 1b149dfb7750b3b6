"""Where a population iteration's time goes: ms of process CPU time per part, per iteration.

The command line over :mod:`lab.bench.population_profile`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.population_profile import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
