"""The weights of ``deploy.weights: feasible``: the best mixture of the run's snapshots within every budget on
their measured values, the linear programme (scipy's HiGHS)

    max_w  sum_i w_i R_i   s.t.  sum_i w_i (C_ik + m se_ik) <= d_k  for every cost k,  sum_i w_i = 1,  w >= 0,

Cotter, Jiang, Sridharan's "shrinking" step (ALT 2019, Sec. 4): at most K + 1 members, ``m`` standard errors
inside the budget (docs/constraint_satisfaction.md). Members are valued on episodes seeded apart from the
final evaluation, which then measures the chosen mixture afresh."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np
import torch
from scipy.optimize import linprog

from cmdp_rl.algos.base import per_constraint
from cmdp_rl.deploy.mixture import mixture_actor
from cmdp_rl.envs import make_eval_env
from cmdp_rl.rollout.collector import Collector, episode_rows

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig
    from cmdp_rl.deploy.mixture import IterateSnapshots
    from cmdp_rl.policies.agent import Actor, Agent

# A member valuation's evaluation seed is the run's seed plus this: neither a training seed nor
# the final evaluation's (evaluation.EVAL_SEED_OFFSET).
VALUATION_SEED_OFFSET = 2_000_003


@dataclass(frozen=True)
class MemberValue:
    """One member's measured mean return, mean costs and their standard errors over its episodes."""

    episode_return: float
    episode_cost: tuple[float, ...]
    cost_se: tuple[float, ...]
    episodes: int
    steps: int = 0  # the env steps its episodes took: what valuing it cost

    def as_dict(self) -> dict:
        """What a checkpoint and eval.json keep of it (not its cost in steps)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items() if k != "steps"}


def feasible_weights(
    values: Sequence[MemberValue], budgets: Sequence[float], margin: float
) -> tuple[list[float], bool]:
    """The mixture weights over ``values`` and whether the programme was feasible; if not, all the weight goes
    to the member with the smallest largest violation relative to each budget (ties: higher return)."""
    returns = np.array([v.episode_return for v in values])
    upper = np.array([[c + margin * s for c, s in zip(v.episode_cost, v.cost_se)] for v in values])  # [M, K]
    d = np.asarray(budgets, dtype=float)
    m = len(values)
    solved = linprog(-returns, A_ub=upper.T, b_ub=d, A_eq=np.ones((1, m)), b_eq=[1.0], bounds=(0, 1), method="highs")
    if solved.status == 0:
        w = np.where(solved.x > 1e-9, solved.x, 0.0)
        return (w / w.sum()).tolist(), True
    scale = np.where(d > 0, d, 1.0)
    worst = ((upper - d) / scale).max(axis=1)
    best = min(range(m), key=lambda i: (worst[i], -returns[i]))
    return [1.0 if i == best else 0.0 for i in range(m)], False


def member_episodes(actors: list[Actor], agent: Agent, cfg: RunConfig, episodes: int, seed: int) -> list[np.ndarray]:
    """Each of ``actors``' rows (return, length, terminated, cost_0, ...) over at least ``episodes`` evaluation
    episodes seeded with ``seed``, all in one batch, each actor on its own env rows."""
    m = len(actors)
    env_cfg = cfg.env.valuation_options()  # the same CMDP, batched where the env has a batched twin
    batched = getattr(env_cfg, "backend", None) == "torch"
    rows_each = max(1, min(episodes, 64 if batched else env_cfg.num_envs // m))
    quota = math.ceil(episodes / rows_each)
    env = make_eval_env(env_cfg, num_envs=m * rows_each, device=cfg.device, algo=cfg.algo)
    own = agent.actor
    agent.actor = mixture_actor(actors, assigned=torch.arange(m * rows_each, device=env.device) % m)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            collector = Collector(env, agent, 128, seed=seed, deterministic=cfg.eval_deterministic)
            rows = episode_rows(collector, [quota] * (m * rows_each))
    finally:
        agent.actor = own
        env.close()
    return [np.array([row for r in rows[i::m] for row in r], dtype=float) for i in range(m)]


def value_members(actors: list[Actor], agent: Agent, cfg: RunConfig, num_costs: int) -> list[MemberValue]:
    """Each of ``actors``' mean return and costs over at least ``cfg.deploy.episodes`` evaluation episodes
    (seed + ``VALUATION_SEED_OFFSET``, :func:`member_episodes`)."""
    values = []
    for mine in member_episodes(actors, agent, cfg, cfg.deploy.episodes, cfg.seed + VALUATION_SEED_OFFSET):
        costs = mine[:, 3 : 3 + num_costs]
        se = costs.std(axis=0, ddof=1) / math.sqrt(len(mine)) if len(mine) > 1 else np.zeros(num_costs)
        ret, steps = float(mine[:, 0].mean()), int(mine[:, 1].sum())
        values.append(MemberValue(ret, tuple(costs.mean(0).tolist()), tuple(se.tolist()), len(mine), steps))
    return values


def choose_weights(snapshots: IterateSnapshots, agent: Agent, cfg: RunConfig, names: Sequence[str]) -> str:
    """Value ``snapshots``' members, weight them as the best mixture within budget; one line saying what."""
    budgets = per_constraint(cfg.algo.cost_limit, "algo.cost_limit", names)
    values = value_members(snapshots.actors(agent.actor), agent, cfg, len(names))
    weights, feasible = feasible_weights(values, budgets, cfg.deploy.margin)
    snapshots.weights, snapshots.feasible = weights, feasible
    snapshots.values = [v.as_dict() for v in values]
    snapshots.margin = cfg.deploy.margin
    snapshots.valuation_steps = sum(v.steps for v in values)
    chosen = ", ".join(f"iteration {it} ({w:.2f})" for it, w in snapshots.deployed_members())
    valued = (
        f"mixture: {len(values)} snapshots valued over {values[0].episodes} episodes each "
        f"({snapshots.valuation_steps:,} env steps)"
    )
    if feasible:
        return f"{valued}; deployed {chosen}, within budget with costs taken {cfg.deploy.margin:g} standard errors high"
    return (
        f"{valued}; no mixture is within budget on their values "
        f"(costs + {cfg.deploy.margin:g} standard errors); deployed the least violating, {chosen}"
    )
