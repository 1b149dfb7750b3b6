"""The held-out deploy-rule study (lab/studies/heldout_deploy_rules.py): a split values the snapshots on some
episodes and measures the chosen mixture on the others."""

import numpy as np

from lab.studies.heldout_deploy_rules import split_choice


def test_the_best_snapshot_within_budget_is_chosen_and_measured_on_the_other_episodes():
    rng = np.random.default_rng(0)
    returns = [np.full(10, 1.0), np.full(10, 2.0)]
    costs = [np.zeros(10), np.zeros(10)]
    assert split_choice(returns, costs, budget=1.0, valued=4, margin=3.0, rng=rng) == (2.0, 0.0)
    # the better snapshot over budget on its own: the mixture at the budget, measured where it was chosen
    costs = [np.zeros(10), np.full(10, 4.0)]
    ret, cost = split_choice(returns, costs, budget=1.0, valued=4, margin=0.0, rng=rng)
    assert (ret, cost) == (1.25, 1.0)


def test_the_margin_counts_the_valued_episodes_spread():
    rng = np.random.default_rng(1)
    spread = np.array([0.0, 1.0] * 5)  # any 6 of them have a spread: a standard error of 0.15-0.21
    returns, costs = [np.full(10, 1.0), np.full(10, 2.0)], [np.zeros(10), spread]
    for _ in range(20):  # over many splits
        assert split_choice(returns, costs, budget=0.6, valued=6, margin=0.0, rng=rng)[0] >= 1.7  # mostly snapshot 1
        assert split_choice(returns, costs, budget=0.6, valued=6, margin=100.0, rng=rng)[0] < 1.05  # hardly any
