"""The README's first command (`make train`) for several seeds: the figures docs/guide/first_run.md quotes.

The command line over :mod:`lab.bench.first_run`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.first_run import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
