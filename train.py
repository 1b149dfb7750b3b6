"""Train a constrained-RL agent from the checkout: ``python train.py algo=ppo_lag env=reach1d [overrides]``.

The same command as ``cmdp-train`` and ``python -m cmdp_rl`` (:mod:`cmdp_rl.cli.train`, where the
options are described); kept at the root so that a checkout runs without installing.
"""

from cmdp_rl.cli.train import main

if __name__ == "__main__":
    main()
