"""Benchmarks, speed and fidelity measurements: the code behind ``experiments/benchmarks/``,
``experiments/speed/`` and ``experiments/fidelity/``, whose scripts are thin command lines over it.

- ``algorithm_table`` (the page) and ``algorithm_rows`` (its per-task rows, tables and figures):
  every algorithm on the grid, Reach1D and HalfCheetah velocity (docs/algorithms.md);
- ``first_run``: the Makefile's ``make train`` recipe over seeds (docs/guide/first_run.md's figures);
- ``library_example``: the library guide's example (docs/guide/library.md), timed with and without the thread setting;
- ``velocity_benchmark``, ``safety_gym_benchmark``: those benchmarks' sweeps and reports
  (docs/benchmarks.md, docs/safety_gym.md); ``safety_gym_speed``: Safety-Gymnasium's own loop against
  our collector;
- ``safe_nav_fidelity``: the batched torch navigation tasks against Safety-Gymnasium (docs/safe_nav.md).

These drivers run from a checkout (they start ``train.py`` sweeps and write into ``docs/``).
"""
