"""env=safe_nav on MuJoCo Warp against MuJoCo: env steps/s and ppo_lag training steps/s against N.

    python experiments/speed/safe_nav_warp_speed.py [--device cpu|cuda] [--task PointGoal1]
        [--num-envs 1 16 256 4096 16384] [--steps 200] [--train-num-envs 16 4096]
        [--train-steps 65536] [--mujoco-max-envs 256] [--out outputs/safe_nav_warp_speed.json]

The command line over :mod:`lab.bench.safe_nav_warp_speed`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl

from lab.bench.safe_nav_warp_speed import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
