"""Interval estimates of one run's final evaluation over its episodes (docs/evaluation.md): mean return and
cost with a two-sided 95% BCa bootstrap interval (Efron 1987; ``scipy.stats.bootstrap``, a fixed seed) and the
cost's one-sided upper bound; the violation rate with the exact binomial (Clopper-Pearson 1934) interval and
bound. Resampling cannot show spread the sample lacks: equal values give ``no_spread``; one episode, ``None``."""

from __future__ import annotations

import math
import warnings
from typing import Any, Sequence

import numpy as np
from scipy import stats

LEVEL = 0.95  # the key names below say "95"
RESAMPLES = 9999  # scipy's default
SEED = 0  # the bootstrap's own generator, independent of torch's: intervals never move training
BOOTSTRAP_METHOD = "BCa bootstrap over episodes (scipy.stats.bootstrap)"
BINOMIAL_METHOD = "exact binomial, Clopper-Pearson (scipy.stats.binomtest)"
# Episode costs are float sums of per-step costs: a cost equal to the budget up to rounding (e.g.
# 0.1 + 0.2 against d = 0.3) is not a violation.
VIOLATION_TOLERANCE = 1e-9


def mean_interval(values: Sequence[float], resamples: int = RESAMPLES, seed: int = SEED) -> dict[str, Any]:
    """Mean of ``values`` with a two-sided 95% BCa bootstrap interval (``low``, ``high``) and the
    one-sided upper bound (``upper``); ``no_spread`` when all values are equal; None bounds for one value."""
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1 or x.size == 0:
        raise ValueError(f"mean_interval: need a non-empty 1-D sample, got shape {x.shape}")
    mean = float(x.mean())
    out: dict[str, Any] = {"mean": mean, "n": int(x.size), **dict.fromkeys(("low", "high", "upper"))}
    out["no_spread"] = bool(np.ptp(x) == 0)
    if x.size < 2:
        return out
    if out["no_spread"]:
        out.update(low=mean, high=mean, upper=mean)
        return out
    kwargs = dict(statistic=np.mean, confidence_level=LEVEL, method="BCa")
    with warnings.catch_warnings():
        # BCa is undefined for some near-degenerate samples (scipy warns and returns NaN); the
        # percentile interval of the same resamples is used there instead (below).
        warnings.simplefilter("ignore")
        two = stats.bootstrap((x,), n_resamples=resamples, rng=np.random.default_rng(seed), **kwargs)
        one = stats.bootstrap((x,), n_resamples=0, bootstrap_result=two, alternative="less", **kwargs)
        low, high, upper = two.confidence_interval.low, two.confidence_interval.high, one.confidence_interval.high
        if not all(map(math.isfinite, (low, high, upper))):
            kwargs["method"] = "percentile"
            two = stats.bootstrap((x,), n_resamples=0, bootstrap_result=two, **kwargs)
            one = stats.bootstrap((x,), n_resamples=0, bootstrap_result=two, alternative="less", **kwargs)
            low, high, upper = two.confidence_interval.low, two.confidence_interval.high, one.confidence_interval.high
            out["method"] = "percentile"
    out.update(low=float(low), high=float(high), upper=float(upper))
    return out


def violation_interval(costs: Sequence[float], cost_limit: float) -> dict[str, Any]:
    """The fraction of episodes with cost above ``cost_limit``, with its 95% Clopper-Pearson two-sided interval
    (``low``, ``high``) and one-sided upper bound (``upper``)."""
    c = np.asarray(costs, dtype=np.float64)
    if c.ndim != 1 or c.size == 0:
        raise ValueError(f"violation_interval: need a non-empty 1-D sample, got shape {c.shape}")
    n = int(c.size)
    k = int(np.sum(c > cost_limit + VIOLATION_TOLERANCE * max(1.0, abs(cost_limit))))
    two = stats.binomtest(k, n).proportion_ci(confidence_level=LEVEL, method="exact")
    one = stats.binomtest(k, n, alternative="less").proportion_ci(confidence_level=LEVEL, method="exact")
    return dict(rate=k / n, violations=k, n=n, low=float(two.low), high=float(two.high), upper=float(one.high))


def summarize(
    returns: Sequence[float], costs: Sequence[float], cost_limit: float, resamples: int = RESAMPLES, seed: int = SEED
) -> dict[str, Any]:
    """The interval keys eval.json carries (``[low, high]`` lists; None for unknown bounds)."""
    ret, cost = mean_interval(returns, resamples, seed), mean_interval(costs, resamples, seed)
    viol = violation_interval(costs, cost_limit)

    def pair(r: dict[str, Any]) -> list[float] | None:
        return None if r["low"] is None else [r["low"], r["high"]]

    percentile = [name for name, r in (("episode_return", ret), ("episode_cost", cost)) if r.get("method")]
    return {
        "episode_return_ci95": pair(ret),
        "episode_cost_ci95": pair(cost),
        "episode_cost_ucb95": cost["upper"],
        "violations": viol["violations"],
        "violation_rate": viol["rate"],
        "violation_rate_ci95": [viol["low"], viol["high"]],
        "violation_rate_ucb95": viol["upper"],
        "intervals": {
            "level": LEVEL,
            "method": BOOTSTRAP_METHOD,
            "resamples": resamples,
            "seed": seed,
            "violation_method": BINOMIAL_METHOD,
            "violation": f"episode cost > {cost_limit:g}",
            "no_spread": [name for name, r in (("episode_return", ret), ("episode_cost", cost)) if r["no_spread"]],
            **({"percentile_fallback": percentile} if percentile else {}),
        },
    }


def _ci(pair: list[float] | None, fmt: str) -> str:
    return "no interval (1 episode)" if pair is None else f"95% CI [{pair[0]:{fmt}}, {pair[1]:{fmt}}]"


def summary_lines(result: dict[str, Any], cost_limit: float) -> list[str]:
    """The return's, the cost's and the violations' interval lines of a result holding :func:`summarize`'s keys."""
    n = result["episodes"]
    flat = result["intervals"]["no_spread"]
    ucb = result["episode_cost_ucb95"]
    lines = [
        f"return {result['episode_return']:.3f}, {_ci(result['episode_return_ci95'], '.3f')}"
        + ("; no spread over the episodes" if "episode_return" in flat and n > 1 else ""),
        f"cost   {result['episode_cost']:.2f}, {_ci(result['episode_cost_ci95'], '.2f')}"
        + ("" if ucb is None else f", 95% upper bound {ucb:.2f}")
        + f" (limit {cost_limit:g})",
    ]
    if "episode_cost" in flat and n > 1:
        lines[-1] += (
            f"; every episode had cost {result['episode_cost']:.2f}, so the bootstrap shows no"
            " spread: rest a safety claim on the violation bound"
        )
    lo, hi = result["violation_rate_ci95"]
    lines.append(
        f"violations {result['violations']}/{n} episodes (cost > {cost_limit:g}): rate "
        f"{result['violation_rate']:.0%}, 95% CI [{lo:.0%}, {hi:.0%}], "
        f"95% upper bound {result['violation_rate_ucb95']:.0%}"
    )
    return lines


def episodes_for_violation_bound(bound: float, level: float = LEVEL) -> int:
    """Fewest violation-free episodes whose one-sided Clopper-Pearson upper bound is at most
    ``bound``: the smallest n with ``(1 - level)**(1/n) >= 1 - bound``."""
    if not 0 < bound < 1:
        raise ValueError(f"bound must be in (0, 1), got {bound}")
    return math.ceil(math.log(1 - level) / math.log(1 - bound))
