"""The constraint-satisfaction study's arithmetic (analysis/constraint_satisfaction.py): gap,
relative violation, the t interval and the table's counts, by hand."""

import pytest

from lab.studies.constraint_satisfaction import Outcome, interval, table


def test_gap_violation_and_within_by_hand():
    o = Outcome("fork", "ppo_lag", 0, ret=5.0, optimum=6.25, costs=[1.5, 0.5], budgets=[1.0, 1.0], train_time_s=1.0)
    assert o.gap == pytest.approx(0.2)  # (6.25 - 5) / 6.25
    assert o.violation == pytest.approx([0.5, -0.5])
    assert not o.within


def test_t_interval_and_table_counts():
    m, h = interval([1.0, 2.0, 3.0])
    assert m == 2.0 and h == pytest.approx(4.302653 * 1.0 / 3**0.5, rel=1e-5)  # t_{0.975, 2} * s / sqrt(n)
    rows = [
        Outcome("c", "m", s, ret=r, optimum=1.0, costs=[c], budgets=[1.0], train_time_s=0.0)
        for s, (r, c) in enumerate([(0.95, 0.9), (0.8, 0.9), (1.2, 1.5)])
    ]
    line = table(rows).splitlines()[-1]
    assert line.endswith("| 2/3 | 1/3 |")  # within budget: seeds 0 and 1; and within 10%: seed 0 only
