"""The constrained hyperparameter search (docs/tuning.md): ``search``, its input and ask-and-tell loop behind
``hydra/sweeper=cmdp_optuna``; ``trial``, a trial's observer, outcome and feasibility rule; ``report``, its report."""
