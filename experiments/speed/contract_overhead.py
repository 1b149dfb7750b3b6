"""What the per-rollout env-contract check (``envs/contract.py: check_rollout``) costs in training.

The command line over :mod:`lab.bench.contract_overhead`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.contract_overhead import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
