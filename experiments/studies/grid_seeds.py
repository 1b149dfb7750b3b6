"""Train ``env=grid`` runs over several seeds, as ``python train.py env=grid algo=<algo> <overrides>``.

The command line over :mod:`lab.studies.grid_seeds`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.studies.grid_seeds import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
