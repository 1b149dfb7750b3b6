"""What the field publishes on Safety-Gymnasium's navigation tasks (budget d = 25), for the campaign's report.

Collected in ``../shared/notes/safe-rl-benchmark-facts.md`` (2026-11-28) from the projects' own files:

- ``ONE_E7``: OmniSafe's on-policy benchmark table, mean ± std over 5 seeds at 1e7 steps
  (github.com/PKU-Alignment/omnisafe, ``benchmarks/on-policy/README.md``, Table 2);
- ``CURVES``: the 1M and 2M values read off the learning-curve images those READMEs embed (OmniSafe: 5 seeds;
  FSRL, github.com/liuzuxin/FSRL ``docs/_static/images/safety-gymnasium-navigation/``: 3 seeds), to about ±1–2
  of return and ±3–5 of cost. They are training episodes of the sampled policy, smoothed, not evaluations.

Keys are this toolkit's algorithm names; the value names the source's own algorithm.
"""

from __future__ import annotations

OMNISAFE_1E7 = "OmniSafe, benchmarks/on-policy/README.md, Table 2 (1e7 steps, 5 seeds)"
OMNISAFE_CURVES = "OmniSafe's benchmark curves (benchmarks/on-policy/README.md), read at 1M and 2M steps"
FSRL_CURVES = "FSRL's curves (docs/_static/images/safety-gymnasium-navigation/), read at 1M and 2M steps"

# task -> algo -> (source's name, source, (R, C) at 1M, (R, C) at 2M)
CURVES: dict[str, dict[str, tuple[str, str, tuple[float, float], tuple[float, float]]]] = {
    "PointGoal1": {
        "ppo": ("PPO", OMNISAFE_CURVES, (24.6, 52), (25.7, 55)),
        "ppo_lag": ("PPOLag", OMNISAFE_CURVES, (18.6, 51), (19.2, 45)),
        "pid_lag": ("CPPOPID", OMNISAFE_CURVES, (0.7, 17), (2.7, 24)),
        "trpo_lag": ("TRPOLag", OMNISAFE_CURVES, (5.4, 22), (7.2, 16)),
        "cpo": ("CPO", OMNISAFE_CURVES, (9.8, 45), (11.2, 35)),
        "focops": ("FOCOPS", OMNISAFE_CURVES, (22.2, 47), (16.5, 35)),
        "cup": ("CUP", OMNISAFE_CURVES, (6.4, 19), (12.4, 29)),
    },
    "CarGoal1": {
        "ppo": ("PPO", OMNISAFE_CURVES, (30.2, 66), (32.2, 65)),
        "ppo_lag": ("PPOLag", OMNISAFE_CURVES, (19.7, 60), (19.2, 46)),
        "focops": ("FOCOPS", OMNISAFE_CURVES, (26.1, 42), (17.6, 29)),
        "cup": ("CUP", OMNISAFE_CURVES, (2.2, 19), (6.3, 20)),
    },
    "PointButton1": {
        "ppo_lag": ("PPOLag", OMNISAFE_CURVES, (7.4, 78), (4.4, 43)),
    },
}
# FSRL's curves where OmniSafe has none of the algorithm (PointGoal1; FSRL's ppol is PPO-Lag with a PID λ).
FSRL: dict[str, dict[str, tuple[str, str, tuple[float, float], tuple[float, float]]]] = {
    "PointGoal1": {
        "pid_lag": ("ppol (PID λ)", FSRL_CURVES, (13.9, 38), (19.8, 41)),
        "cpo": ("CPO", FSRL_CURVES, (10.3, 25), (13.0, 26)),
    },
}

# task -> algo -> (source's name, R mean, R std, C mean, C std) at 1e7 steps.
ONE_E7: dict[str, dict[str, tuple[str, float, float, float, float]]] = {
    "PointGoal1": {
        "ppo": ("PPO", 25.44, 5.43, 55.72, 35.55),
        "ppo_lag": ("PPOLag", 12.96, 6.95, 25.80, 34.99),
        "pid_lag": ("CPPOPID", 8.43, 3.43, 25.74, 7.83),
        "trpo_lag": ("TRPOLag", 18.51, 3.83, 22.98, 8.45),
        "cpo": ("CPO", 20.46, 1.38, 28.84, 7.76),
        "pcpo": ("PCPO", 18.57, 1.71, 22.98, 6.56),
        "focops": ("FOCOPS", 14.97, 9.01, 33.72, 42.24),
        "cup": ("CUP", 14.42, 6.74, 19.02, 20.08),
        "saute": ("PPOSaute", 7.06, 5.85, 20.04, 21.91),
    },
}
# Rows of OmniSafe's 1e7 table with no algorithm of ours by that name, shown beside the 1e7 rows.
ONE_E7_OTHERS = {
    "PointGoal1": [("TRPOPID", 19.24, 3.94, 21.38, 6.96), ("PPOEarlyTerminated", 16.03, 8.60, 19.17, 9.42)]
}


def at_steps(task: str, algo: str, steps: int) -> tuple[str, str, float, float] | None:
    """The published (name, source, R, C) of ``algo`` on ``task`` at 1M or 2M steps, OmniSafe's before FSRL's."""
    index = {1_000_000: 2, 2_000_000: 3}.get(steps)
    if index is None:
        return None
    for table in (CURVES, FSRL):
        entry = table.get(task, {}).get(algo)
        if entry is not None:
            return entry[0], entry[1], *entry[index]
    return None
