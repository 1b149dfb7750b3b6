"""Reading finished sweeps into reports: the pieces the ``experiments/`` scripts share.

- ``stats``: statistics over seeds (mean and spread) and over a run's iterations (tail mean);
- ``tables``: "mean ± std" cells, markdown tables, CSV files;
- ``penalty_constraint``: runs of a penalty-versus-constraint study grouped by algorithm, fixed
  penalty λ or budget d, and start distribution; its table, run status and rerun script;
- ``figures``: that study's figure (cost against λ, cost against d per start distribution);
- ``reach1d_reference``: the exact (dynamic-programming) reference for that study on Reach1D, and
  the seed exercise's answers derived from it.

Reading run directories is ``cmdp_rl.run.sweeps``; nothing here trains.
"""
