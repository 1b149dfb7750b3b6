"""Population training against the same agents trained one after another, in one process.

The command line over :mod:`lab.bench.population_benchmark`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.population_benchmark import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
