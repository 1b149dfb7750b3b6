"""env=safe_nav against the real Safety-Gymnasium tasks, step for step, over whole episodes.

The command line over :mod:`lab.fidelity.safe_nav_fidelity`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.fidelity.safe_nav_fidelity import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
