"""``python -m cmdp_rl [overrides]``: the ``cmdp-train`` command (:mod:`cmdp_rl.cli.train`)."""

from cmdp_rl.cli.train import main

if __name__ == "__main__":
    main()
