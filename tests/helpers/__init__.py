"""What several test modules share, imported as ``from helpers.runs import tiny`` (pytest puts ``tests/`` on the
path; a subprocess gets it through ``PYTHONPATH=tests``). A test module imports from here, never from another
test module or from conftest.py, which holds only fixtures.

- :mod:`helpers.runs`: the tiny run (``TINY``, :func:`~helpers.runs.tiny`) and reading a run's outputs;
- :mod:`helpers.resume`: a run crashed and resumed, compared with the uninterrupted one;
- :mod:`helpers.cli`: ``python train.py ARGS`` run in the test's process (its exit status and output, without a new
  interpreter's seconds of imports);
- :mod:`helpers.golden`: the recorded numbers of ``tests/golden/`` and how a run is compared with them;
- :mod:`helpers.cost_envs`: small gymnasium envs that report costs (discrete actions, K = 2 costs, faults);
- :mod:`helpers.policies`: policies and training batches built by hand.
"""
