"""The command-line entry points: ``cmdp-train`` (also ``python -m cmdp_rl`` and the checkout's
``train.py``), ``cmdp-evaluate`` (``evaluate.py``); ``cmdp-compare`` is :mod:`cmdp_rl.report.compare`."""
