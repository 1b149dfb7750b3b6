"""cmdp_rl's Hydra sweeper for the constrained hyperparameter search (``hydra/sweeper=cmdp_optuna``, docs/tuning.md).

Hydra finds sweepers by importing every module under the ``hydra_plugins`` namespace package, so this one lives
beside ``cmdp_rl/`` (setup.py ships it in the wheel); the search itself is :mod:`cmdp_rl.tune.search`.
"""
