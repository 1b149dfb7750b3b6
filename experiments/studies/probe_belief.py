"""The seed's probe exercise: memoryless and history-dependent policies, with and without a probe.

The command line over :mod:`lab.studies.probe_belief`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.studies.probe_belief import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
