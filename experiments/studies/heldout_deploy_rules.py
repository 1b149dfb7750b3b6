"""The deployed mixture's selection judged on held-out episodes, for envs with no exact values.

The command line over :mod:`lab.studies.heldout_deploy_rules`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl and lab

from lab.studies.heldout_deploy_rules import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
