"""Reading finished sweeps into reports: the pieces the ``experiments/`` scripts share.

- ``stats``: statistics over seeds (mean and spread) and over a run's iterations (tail mean);
- ``tables``: "mean ± std" cells, markdown tables, CSV files;
- ``penalty_constraint``: runs of a penalty-versus-constraint study grouped by algorithm, fixed
  penalty λ or budget d, and start distribution; its table, run status and rerun script;
- ``figures``: that study's figure (cost against λ, cost against d per start distribution);
- ``reach1d_reference``: the exact (dynamic-programming) reference for that study on Reach1D, and
  the seed exercise's answers derived from it;
- ``penalty_vs_constraint``: that study's command (the sweeps' report, the batched grid);
- ``pid_damping``, ``probe_belief``: those studies' reports (docs/pid_and_cpo.md, docs/probe_belief.md);
- ``budget_report``: CPO against PPO-Lagrangian at one budget (docs/pid_and_cpo.md);
- ``grid_seeds``: the gridworld over seeds against its exact optimum (docs/grid.md);
- ``grid_policy``, ``fork_policy``: a trained policy's exact value on the tabular tasks.

``experiments/studies/`` holds the thin command lines over these.

Reading run directories is ``cmdp_rl.report.sweeps``; the study commands start sweeps through ``train.py``.
"""
