"""What one PPO-Lagrangian minibatch step costs at env=safe_nav's default shape, and what public means would cut it.

The command line over :mod:`lab.bench.update_minibatch_cost`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.update_minibatch_cost import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
