"""Issue 43's figures on a GPU (MuJoCo Warp's env=safe_nav, populations with device=cuda), in one call.

    python experiments/speed/gpu_figures.py --stage .gpu                       # here: what the device needs
    cd .gpu && python experiments/speed/gpu_figures.py --wheels whl --payload payload --out $OUT
    python experiments/speed/gpu_figures.py --tiny --device cpu --out /tmp/gpu_figures   # a rehearsal

The command line over :mod:`lab.bench.gpu_figures`, where the code and its documentation live.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's cmdp_rl and lab

from lab.bench.gpu_figures import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
