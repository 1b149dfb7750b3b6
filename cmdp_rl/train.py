"""``python -m cmdp_rl.train [overrides]``: the ``cmdp-train`` command (:mod:`cmdp_rl.cli.train`).

Run it with ``-m``, never import it: importing this module would replace the function
``cmdp_rl.train`` (the trainer) with the module of the same name. ``-m`` executes it as
``__main__`` and leaves the package's attribute alone.
"""

from cmdp_rl.cli.train import main

if __name__ == "__main__":
    main()
