"""Evaluate a trained run from the checkout: ``python evaluate.py run=<run dir> [key=value ...]``.

The same command as ``cmdp-evaluate`` (:mod:`cmdp_rl.cli.evaluate`; ``--help`` lists the options).
"""

import sys

from cmdp_rl.cli.evaluate import main

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
