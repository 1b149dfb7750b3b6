"""Evaluate a policy over a fixed number of whole episodes."""

from __future__ import annotations

from typing import Any, Callable, Sequence

import torch

from cmdp_rl.config.validation import per_constraint
from cmdp_rl.envs import VecEnv
from cmdp_rl.policies.agent import Agent
from cmdp_rl.report.intervals import summarize as interval_estimates
from cmdp_rl.report.metrics import constraint_name
from cmdp_rl.rollout.collector import Collector, episode_rows

EVAL_SEED_OFFSET = 1_000_003  # a run's evaluation seed is its seed plus this: never a training seed
# The two ways to act with a stochastic policy, by their eval.json names: its mean action, and sampled actions (what
# the field's published on-policy curves measure: training episodes of the sampled policy).
MODES = {"mean_action": True, "sampled": False}


def mode_name(deterministic: bool) -> str:
    return "mean_action" if deterministic else "sampled"


def both_modes(evaluate_mode: Callable[[bool], dict[str, Any]], deterministic: bool) -> dict[str, Any]:
    """An evaluation in both :data:`MODES`: the headline mode's result (``deterministic``: the run's
    ``eval_deterministic``, the mode its deployed policy was valued in) at the top level, as before, and
    each mode's under ``modes``; ``evaluate_mode(deterministic)`` runs one."""
    modes = {name: evaluate_mode(det) for name, det in MODES.items()}
    return {**modes[mode_name(deterministic)], "modes": modes}


def _spread(name: str, values: list[float]) -> dict[str, float]:
    t = torch.tensor(values, dtype=torch.float64)
    return {
        name: t.mean().item(),
        f"{name}_std": t.std(unbiased=False).item(),
        f"{name}_min": t.min().item(),
        f"{name}_max": t.max().item(),
    }


def evaluate(
    agent: Agent,
    env: VecEnv,
    episodes: int,
    deterministic: bool = True,
    seed: int | None = None,
    termination_metric: str | None = None,
    cost_limit: float | Sequence[float] | None = None,
) -> dict[str, float]:
    """Run ``episodes`` whole episodes and return means and spreads of return, cost and length; with K > 1 costs
    each constraint's keys carry ``/<cost>`` (``metrics.constraint_name``).

    Each env contributes a fixed quota of its first episodes, so that short episodes (which end first) are not
    over-represented. ``termination_metric`` (an env's name for termination, e.g. Reach1D's ``goal_reached``) adds the
    fraction of episodes that terminated rather than timed out. ``seed`` seeds a stochastic policy's samples inside
    ``fork_rng`` (the caller's generator is left as it was). ``cost_limit`` (d, one or a list of K) adds 95% intervals
    over the episodes (:func:`cmdp_rl.report.intervals.summarize`)."""
    with torch.random.fork_rng(devices=[]):
        if seed is not None:
            torch.manual_seed(seed)
        return evaluate_members(agent, env, episodes, deterministic, [cost_limit], termination_metric, seed)[0]


def evaluate_members(
    agent: Agent,
    env: VecEnv,
    episodes: int,
    deterministic: bool,
    cost_limits: Sequence[Any],
    termination_metric: str | None = None,
    seed: int | None = None,
) -> list[dict[str, Any]]:
    """:func:`evaluate`'s result for each of ``len(cost_limits)`` members side by side in ``env``
    (a run is one; a population's agent i has the rows ``[i n, (i + 1) n)``), each with its own
    budget, ``episodes`` episodes each; the caller seeds the members' action samples."""
    parts = len(cost_limits)
    n = env.num_envs // parts
    # A multi-agent env's M rows of a team end their episodes together (envs/multi_agent.py): an
    # episode is the team's, counted once, its return the mean of the agents' returns.
    m = getattr(env, "agents_per_env", 1)
    teams = n // m
    quota = [episodes // teams + (1 if i // m < episodes % teams else 0) for i in range(n)]
    collector = Collector(env, agent, 128, seed=seed, deterministic=deterministic)  # 128 steps a collect
    everyone = episode_rows(collector, quota * parts)
    results = []
    for j, cost_limit in enumerate(cost_limits):
        rows = everyone[j * n : (j + 1) * n]
        if m > 1:  # the j-th episode of a team: its agents' mean return, its first row's cost and length
            rows = [
                [(sum(rows[i + a][k][0] for a in range(m)) / m, *rows[i][k][1:]) for k in range(quota[i])]
                for i in range(0, n, m)
            ]
        flat = [row for r in rows for row in r]
        results.append(summarize_episodes(flat, env.cost_names, deterministic, termination_metric, cost_limit))
    return results


def summarize_episodes(
    flat: list[tuple[float, ...]],
    names: Sequence[str],
    deterministic: bool,
    termination_metric: str | None = None,
    cost_limit: float | Sequence[float] | None = None,
) -> dict[str, Any]:
    """``evaluate``'s result from its episodes' rows ``(return, length, terminated, cost_0, ...)``: spreads of
    return, each cost and length, the termination rate, and with ``cost_limit`` the intervals (with one cost exactly
    :func:`cmdp_rl.report.intervals.summarize`'s keys; with K > 1 the return's once, the others as ``<key>/<cost>``)."""
    k = len(names)
    returns = [row[0] for row in flat]
    result: dict[str, Any] = {"episodes": len(flat), "deterministic": deterministic}
    result.update(_spread("episode_return", returns))
    for j, cost_name in enumerate(names):
        spread = _spread("episode_cost", [row[3 + j] for row in flat])
        result.update({constraint_name(key, cost_name, k): v for key, v in spread.items()})
    result.update(_spread("episode_length", [row[1] for row in flat]))
    if termination_metric:
        result[termination_metric] = sum(row[2] for row in flat) / len(flat)
    if cost_limit is not None:
        for j, (name, d) in enumerate(zip(names, per_constraint(cost_limit, "cost_limit", names))):
            est = interval_estimates(returns, [row[3 + j] for row in flat], d)
            if k > 1:
                return_ci = est.pop("episode_return_ci95")
                est = {"episode_return_ci95": return_ci, **{f"{key}/{name}": v for key, v in est.items()}}
            result.update(est)
    return result
