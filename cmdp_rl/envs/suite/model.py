"""The generated suite's CMDPs as arrays: how an instance is drawn from its number, and the exact
value of any policy by backward induction.

One instance is a finite-horizon CMDP (Altman 1999, ch. 2) ``(S, A, P, r, c_1..c_K, mu0, H, d)``
whose every episode lasts exactly ``H`` steps. Its values are the undiscounted episode sums
``J(pi) = E[sum_{t < H} r(s_t, a_t)]`` and ``J_c[k]`` likewise, what ``eval.json`` reports; its
optimum depends on the time step as well as the state, so policies here are tables ``pi[t, s, a]``.
What :func:`generate` draws (sizes, scales, the three kinds of budget) and why:
docs/constraint_satisfaction.md, "The generated suite". Tables are redrawn until the trade-off is
real: ``J(pi_safe) <= 0.75 J(pi_r)``, every cost can be changed by the policy, and every budget is at
least 1% of that cost's greatest achievable value (a budget of 0 would make the budget-relative
multiplier step divide by zero).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np
from scipy import sparse

from cmdp_rl.envs.grid.optimum import ConstrainedOptimum, budgets_of, occupancy_lp
from cmdp_rl.envs.grid.tabular import Sizes

TUNING = range(0, 30)  # instance ids that may be used to choose defaults
HELD_ASIDE = range(1000, 1030)  # instance ids never used to choose anything: measured only
SUITE_STREAM = 0x5C17E  # the first word of every instance's seed: its own stream, apart from any run seed
HORIZONS = (10, 200)
SCALES = (1e-2, 1e2)
STATES = (3, 8)
ACTIONS = (2, 4)
NUM_COSTS_P = (0.5, 0.3, 0.2)  # P(K = 1, 2, 3)
BUDGET_KINDS = ("mixed", "vertex", "slack")
BUDGET_KINDS_P = (0.5, 0.25, 0.25)
MAX_REDRAWS = 200


@dataclass(frozen=True, eq=False)
class FiniteCMDP(Sizes):
    """A finite-horizon tabular CMDP and its budgets (module docstring)."""

    P: np.ndarray  # [S, A, S] transition probabilities, rows sum to 1
    r: np.ndarray  # [S, A] reward
    c: np.ndarray  # [K, S, A] costs
    mu0: np.ndarray  # [S] start distribution
    horizon: int
    budgets: np.ndarray  # [K] d
    reward_scale: float = 1.0  # R
    cost_scales: np.ndarray | None = None  # [K] C_k
    cost_range: np.ndarray | None = None  # [K, 2] least and greatest achievable J_c[k]
    budget_kind: str = ""  # how the budgets were drawn: mixed, vertex or slack
    instance: int | None = None

    @property
    def cost_names(self) -> tuple[str, ...]:
        return tuple(f"cost_{k}" for k in range(self.num_costs))


@dataclass(frozen=True, eq=False)
class Values:
    """A policy's exact values (a batch of policies adds its leading dimensions)."""

    ret: np.ndarray  # [...] J(pi)
    costs: np.ndarray  # [..., K] J_c(pi)


def evaluate(cmdp: FiniteCMDP, policy: np.ndarray) -> Values:
    """Exact ``J`` and ``J_c`` of ``policy[..., t, s, a] = pi_t(a | s)`` (a stationary ``[S, A]`` table:
    the same at every step) by backward induction: ``V_H = 0``, ``V_t(s) = sum_a pi_t(a | s) (g(s, a) +
    sum_s' P(s' | s, a) V_{t+1}(s'))`` for the reward and each cost ``g`` at once; then ``J = mu0 . V_0``."""
    pi = np.asarray(policy, dtype=np.float64)
    shape = (cmdp.num_states, cmdp.num_actions)
    if pi.shape == shape:
        pi = np.broadcast_to(pi, (cmdp.horizon, *shape))
    if pi.shape[-3:] != (cmdp.horizon, *shape):
        raise ValueError(f"policy: expected shape [..., {cmdp.horizon}, {shape[0]}, {shape[1]}], got {pi.shape}")
    signals = np.concatenate([cmdp.r[None], cmdp.c])  # [1 + K, S, A]
    v = np.zeros((*pi.shape[:-3], 1 + cmdp.num_costs, cmdp.num_states))
    for t in reversed(range(cmdp.horizon)):
        q = signals + np.einsum("sap,...kp->...ksa", cmdp.P, v)
        v = np.einsum("...sa,...ksa->...ks", pi[..., t, :, :], q)
    totals = np.einsum("s,...ks->...k", cmdp.mu0, v)
    return Values(ret=totals[..., 0], costs=totals[..., 1:])


def greedy(cmdp: FiniteCMDP, reward: np.ndarray) -> tuple[np.ndarray, float]:
    """The optimal deterministic policy ``[H, S, A]`` (one-hot) of the MDP with ``reward[s, a]``
    over the horizon, by backward induction, and its optimal value ``mu0 . V_0``."""
    v = np.zeros(cmdp.num_states)
    table = np.zeros((cmdp.horizon, cmdp.num_states, cmdp.num_actions))
    eye = np.eye(cmdp.num_actions)
    for t in reversed(range(cmdp.horizon)):
        q = reward + cmdp.P @ v
        best = q.argmax(axis=1)
        table[t] = eye[best]
        v = q[np.arange(cmdp.num_states), best]
    return table, float(cmdp.mu0 @ v)


def _random_tables(rng: np.random.Generator, S: int, A: int, reward_scale: float, cost_scales: np.ndarray):
    P = np.zeros((S, A, S))
    for s in range(S):
        for a in range(A):
            support = rng.choice(S, size=int(rng.integers(1, min(3, S) + 1)), replace=False)
            P[s, a, support] = rng.dirichlet(np.ones(support.size))
    u = rng.random((S, A)) ** 2
    rho = rng.uniform(0.5, 1.0, size=(len(cost_scales), 1, 1))
    mask = rng.random((len(cost_scales), S, A)) < 0.7
    c = cost_scales[:, None, None] * (rho * u + (1 - rho) * rng.random((len(cost_scales), S, A))) * mask
    starts = rng.choice(S, size=int(rng.integers(1, 3)), replace=False)
    mu0 = np.zeros(S)
    mu0[starts] = rng.dirichlet(np.ones(starts.size))
    return P, reward_scale * u, c, mu0


def _budgets(rng: np.random.Generator, cmdp: FiniteCMDP, kind: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The budgets of ``kind`` (module docstring) and the costs' achievable ranges ``[K, 2]``, or
    None where the tables make no real trade-off (the caller redraws them)."""
    K = cmdp.num_costs
    lo = np.array([-greedy(cmdp, -cmdp.c[k])[1] for k in range(K)])
    hi = np.array([greedy(cmdp, cmdp.c[k])[1] for k in range(K)])
    pi_r, _ = greedy(cmdp, cmdp.r)
    pi_safe, _ = greedy(cmdp, -(cmdp.c / cmdp.cost_scales[:, None, None]).sum(0))
    at_r, at_safe = evaluate(cmdp, pi_r), evaluate(cmdp, pi_safe)
    if np.any(hi - lo <= 1e-9 * hi) or at_safe.ret > 0.75 * at_r.ret:
        return None
    if kind == "mixed":
        f = rng.uniform(0.15, 0.85)
        d = (1 - f) * at_safe.costs + f * at_r.costs
    elif kind == "slack":
        d = at_r.costs + rng.uniform(0.2, 0.8, size=K) * (hi - at_r.costs)
    else:  # vertex: draw lambda until its greedy policy gives up reward (the budget binds)
        for _ in range(20):
            lam = cmdp.reward_scale / cmdp.cost_scales * 10 ** rng.uniform(-1.0, 1.0, size=K)
            pi_lam, _ = greedy(cmdp, cmdp.r - np.einsum("k,ksa->sa", lam, cmdp.c))
            at_lam = evaluate(cmdp, pi_lam)
            if at_lam.ret < at_r.ret * (1 - 1e-6):
                break
        else:
            return None
        d = at_lam.costs
    if np.any(d < 0.01 * hi):
        return None
    return d, np.stack([lo, hi], axis=1)


def draw(
    rng: np.random.Generator,
    num_states: int,
    num_actions: int,
    horizon: int,
    kind: str = "mixed",
    reward_scale: float = 1.0,
    cost_scales: np.ndarray | None = None,
    instance: int | None = None,
) -> FiniteCMDP:
    """A CMDP of these sizes and scales (``cost_scales``: one per cost, default one cost of scale 1)
    with budgets of ``kind``, its tables drawn from ``rng`` until the trade-off is real (module
    docstring). :func:`generate` draws the sizes too; a test draws tiny ones here."""
    scales = np.ones(1) if cost_scales is None else np.asarray(cost_scales, dtype=float)
    K = scales.size
    if kind not in BUDGET_KINDS:
        raise ValueError(f"suite budget kind must be one of {BUDGET_KINDS}, got {kind!r}")
    for _ in range(MAX_REDRAWS):
        P, r, c, mu0 = _random_tables(rng, num_states, num_actions, reward_scale, scales)
        cmdp = FiniteCMDP(P, r, c, mu0, horizon, np.full(K, np.inf), reward_scale, scales, None, kind, instance)
        drawn = _budgets(rng, cmdp, kind)
        if drawn is not None:
            d, cost_range = drawn
            return FiniteCMDP(P, r, c, mu0, horizon, d, reward_scale, scales, cost_range, kind, instance)
    raise RuntimeError(f"suite: no trade-off in {MAX_REDRAWS} draws of the tables (instance {instance})")


@lru_cache(maxsize=256)
def generate(instance: int) -> FiniteCMDP:
    """Instance ``instance`` (an integer >= 0) of the suite, the same on every machine and version
    of numpy that keeps ``default_rng``'s streams (module docstring)."""
    if isinstance(instance, bool) or not isinstance(instance, (int, np.integer)) or instance < 0:
        raise ValueError(f"suite instance must be an integer >= 0, got {instance!r}")
    rng = np.random.default_rng((SUITE_STREAM, int(instance)))
    K = int(rng.choice(3, p=NUM_COSTS_P)) + 1
    S = int(rng.integers(STATES[0], STATES[1] + 1))
    A = int(rng.integers(ACTIONS[0], ACTIONS[1] + 1))
    H = int(round(HORIZONS[0] * (HORIZONS[1] / HORIZONS[0]) ** rng.random()))
    log_lo, log_hi = np.log10(SCALES)
    reward_scale = float(10 ** rng.uniform(log_lo, log_hi))
    cost_scales = 10 ** rng.uniform(log_lo, log_hi, size=K)
    kind = str(rng.choice(BUDGET_KINDS, p=BUDGET_KINDS_P))
    return draw(rng, S, A, H, kind, reward_scale, cost_scales, int(instance))


def solve(cmdp: FiniteCMDP, budgets: float | Sequence[float] | None = None) -> ConstrainedOptimum:
    """``max_pi J(pi)`` s.t. ``J_c[k](pi) <= budgets[k]`` (None: the instance's budgets; an infinite
    budget: no constraint), exactly: ``grid/optimum.py``'s occupancy LP over the states (t, s)
    (Altman 1999, ch. 3; Puterman 1994, sec. 6.9), whose flow rows are

        sum_a x_0(s, a)     = mu0(s)
        sum_a x_{t+1}(s, a) = sum_{s', a'} P(s | s', a') x_t(s', a')      for t < H - 1

    for the occupancy ``x_t(s, a) = P(s_t = s, a_t = a)``; the optimum's arrays are ``[H, S, ...]``
    (where it randomises in no (t, s), a deterministic policy is optimal)."""
    h, s, a, k = cmdp.horizon, cmdp.num_states, cmdp.num_actions, cmdp.num_costs
    # Variables x_t(s, a) in (t, s, a) order; step t - 1 sends P's mass into step t.
    inflow = sparse.kron(sparse.eye(h, k=-1), sparse.csr_matrix(cmdp.P.reshape(s * a, s).T))
    return occupancy_lp(
        inflow,
        np.tile(cmdp.r.reshape(-1), h),
        np.tile(cmdp.c.reshape(k, -1), (1, h)),
        np.concatenate([cmdp.mu0, np.zeros((h - 1) * s)]),
        budgets_of(budgets, k, cmdp.budgets),
        (h, s, a),
    )
