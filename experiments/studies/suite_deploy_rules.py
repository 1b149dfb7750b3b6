"""What the deployed mixture's selection is worth on the generated suite, from finished runs, with no training.

The command line over :mod:`lab.studies.suite_deploy_rules`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl and lab

from lab.studies.suite_deploy_rules import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
