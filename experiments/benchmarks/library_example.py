"""Run the library guide's example exactly as written and print its wall time.

The command line over :mod:`lab.bench.library_example`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.library_example import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
