"""Benchmarks, speed and fidelity measurements: the code behind ``experiments/benchmarks/``,
``experiments/speed/`` and ``experiments/fidelity/``, whose scripts are thin command lines over it.

Benchmarks:

- ``algorithm_table`` (the page) and ``algorithm_rows`` (its per-task rows, tables and figures):
  every algorithm on the grid, Reach1D and HalfCheetah velocity (docs/algorithms.md);
- ``first_run``: the Makefile's ``make train`` recipe over seeds (docs/guide/first_run.md's figures);
- ``library_example``: the library guide's example (docs/guide/library.md), timed with and without the
  thread setting;
- ``velocity_benchmark``, ``safety_gym_benchmark``, ``off_policy_benchmark``: those benchmarks' sweeps and
  reports (docs/benchmarks.md, docs/safety_gym.md, docs/off_policy.md).

Speed (docs/throughput.md, docs/population.md, docs/safe_nav.md, docs/safety_gym.md):

- ``benchmark_throughput`` (the table, ``make bench``) over ``throughput_rates`` (its measurements);
  ``update_cost``, ``profile_training``, ``contract_overhead``, ``speed_between_commits``;
- ``population_benchmark``, ``population_profile``; ``off_policy_speed``, ``velocity_speed``;
- ``safety_gym_speed``, ``safety_gym_profile``, ``safe_nav_speed``, ``safe_nav_profile`` (the profile of
  training against the physics bound) and ``update_minibatch_cost`` (a PPO minibatch step's cost).

Fidelity: ``safe_nav_fidelity``, the batched torch navigation tasks against Safety-Gymnasium
(docs/safe_nav.md). The Safety-Gymnasium fidelity check stays a script of its own
(``experiments/fidelity/safety_gym_fidelity.py``): it runs itself again inside a virtual environment
pinned to the original package's versions, where this package is not installed.

These drivers run from a checkout (they start ``train.py`` sweeps and write into ``outputs/``).
"""
