"""The constraint's measured J_c and the multiplier that prices ``J_c - d``: the estimate of J_c every
constrained algorithm compares with its budget (:class:`EpisodeCostEstimate`), and the lambda controllers
that step on it, one per constraint, built from the options node ``algo.multiplier``
(``multiplier_options.py``, one options class per kind).

The Lagrangian of ``max J_r  s.t.  J_c <= d`` is ``J_r - lambda (J_c - d)``; every controller steps on
the violation ``g = (J_c - d) / s``, ``s = d`` with ``scale: budget`` (one step size then means the same
on a budget of 0.15 as on one of 25), else 1. The default, :class:`LogDual`, steps on ``log lambda`` once per
finished episode; why, and what the others measured: docs/constraint_satisfaction.md.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque
from typing import Callable, NamedTuple, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import finished_episodes

# --- The measured J_c ------------------------------------------------------------------------
# J_c, the expected undiscounted episode cost, one definition for every algorithm, per constraint. Per
# iteration: 1. the mean cost (and length) of the episodes that ended in this batch; 2. if none did
# (episodes longer than a rollout), of the last ``window`` that ended before (default: one per env);
# 3. if none has ended yet, the running episodes' cost so far, a lower bound. So lambda moves every iteration.
# Beside it, per constraint, the mean of the last EPISODE_WINDOW finished episodes and how many of them ended in
# this batch: what a dual that steps per finished episode reads (:class:`LogDual`), so that 16 episodes ending
# together every 8th iteration count once, not 8 times.

FINISHED, WINDOW, RUNNING = "finished", "window", "running"
EPISODE_WINDOW = 100  # finished episodes the per-episode J_c averages (OmniSafe's window_lens: 100)


class EpisodeCost(NamedTuple):
    costs: tuple[float, ...]  # J_c estimate, one per constraint
    length: float  # mean episode length of the same episodes
    source: str  # FINISHED, WINDOW or RUNNING (the cases above)
    window_costs: tuple[float, ...] | None = None  # the last EPISODE_WINDOW finished episodes' mean, per constraint
    fresh: int = 0  # how many of them ended in this batch

    @property
    def cost(self) -> float:
        """The J_c estimate of an env with one constraint."""
        if len(self.costs) != 1:
            raise ValueError(f"EpisodeCost.cost: there are {len(self.costs)} constraints; read costs")
        return self.costs[0]


class EpisodeCostEstimate:
    """J_c per iteration from the collector's batches (the cases above)."""

    def __init__(self, window: int | None = None) -> None:
        """``window``: episodes kept; None: one per env, the first batch's ``num_envs``."""
        if window is not None and window < 1:
            raise ValueError(f"window must be a positive integer, got {window}")
        self.window = window
        self._recent: deque[tuple[float, ...]] = deque(maxlen=window)  # (cost_0, ..., cost_{K-1}, length)
        self._episodes: deque[tuple[float, ...]] = deque(maxlen=EPISODE_WINDOW)  # (cost_0, ..., cost_{K-1})

    def update(self, batch: TensorDictBase) -> EpisodeCost:
        if self.window is None:
            self.window = batch.shape[0]
            self._recent = deque(self._recent, maxlen=self.window)
        eps = finished_episodes(batch)
        cost, length = eps["cost"], eps["length"]  # [E, K], [E]
        self._episodes.extend(tuple(c) for c in cost.tolist())
        window = {"fresh": int(length.numel())}
        if self._episodes:
            window["window_costs"] = _column_means(torch.tensor(list(self._episodes), dtype=torch.float64))
        if length.numel():
            self._recent.extend((*c, n) for c, n in zip(cost.tolist(), length.tolist()))
            return EpisodeCost(_column_means(cost), length.mean().item(), FINISHED, **window)
        if self._recent:
            recent = torch.tensor(list(self._recent), dtype=torch.float64)
            return EpisodeCost(_column_means(recent[:, :-1]), recent[:, -1].mean().item(), WINDOW, **window)
        last = batch.get(keys.NEXT)[:, -1]
        return EpisodeCost(
            _column_means(last.get(keys.EPISODE_COST).float()),
            last.get(keys.EPISODE_LENGTH).float().mean().item(),
            RUNNING,
            **window,
        )

    def state_dict(self) -> dict:
        return {"recent": list(self._recent), "window": self.window, "episodes": list(self._episodes)}

    def load_state_dict(self, state: dict) -> None:
        self.window = state.get("window", self.window)
        self._recent = deque((tuple(r) for r in state.get("recent", [])), maxlen=self.window)
        # (a checkpoint from before the per-episode window holds none: it refills from the next episodes)
        self._episodes = deque((tuple(r) for r in state.get("episodes", [])), maxlen=EPISODE_WINDOW)


def _column_means(x: torch.Tensor) -> tuple[float, ...]:
    """The mean of each column of ``[rows, K]``, each reduced as one column on its own."""
    return tuple(x[:, k].mean().item() for k in range(x.shape[1]))


# --- The controllers: lambda >= 0 from one measured J_c per iteration ----------------------


class MultiplierController(ABC):
    """Sets lambda >= 0 (``value``, the lambda in force) from one measurement of J_c per iteration."""

    # The update is projected onto [0, maximum] (``algo.multiplier.max``; FOCOPS's clamp on nu).
    maximum: float = math.inf
    state: tuple[str, ...] = ()  # what a checkpoint keeps besides ``value``
    per_episode = False  # True: steps on the window's J_c, weighted by its share of fresh episodes (step())

    def __init__(self, cost_limit: float, init: float = 0.0, scale: float = 1.0) -> None:
        if init < 0:
            raise ValueError(f"algo.multiplier.init must be >= 0, got {init}")
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"the violation's scale must be a positive number, got {scale}")
        self.cost_limit = cost_limit
        self.scale = float(scale)
        self.value = float(init)

    @property
    def values(self) -> list[float]:
        return [self.value]

    def violation(self, episode_cost: float) -> float:
        """``g = (J_c - d) / scale``: the dual gradient the controllers step on."""
        return (episode_cost - self.cost_limit) / self.scale

    def update(self, episode_cost: float, fresh: float = 1.0) -> float:
        """Take in ``J_c`` (finite) and, for a per-episode controller, the share ``fresh`` of its window that is new;
        update and return the new lambda."""
        if not math.isfinite(episode_cost):
            raise ValueError(f"episode_cost must be finite, got {episode_cost}")
        self.value = min(self.maximum, self._next_value(float(episode_cost), fresh))
        assert self.value >= 0.0
        return self.value

    @abstractmethod
    def _next_value(self, episode_cost: float, fresh: float) -> float:
        """The new lambda (>= 0) after measuring ``episode_cost``."""

    def state_dict(self) -> dict:
        return {"value": self.value, **{k: getattr(self, k) for k in self.state}}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])
        for k in self.state:
            setattr(self, k, None if state.get(k) is None else float(state[k]))


class DualAscent(MultiplierController):
    """``lambda <- max(0, lambda + lr g)``: PPO-Lagrangian's dual ascent (Achiam et al. 2017, eq. 16)."""

    def __init__(self, cost_limit: float, lr: float, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        self.lr = lr

    def _next_value(self, episode_cost: float, fresh: float = 1.0) -> float:
        return max(0.0, self.value + self.lr * self.violation(episode_cost))


class LogDual(MultiplierController):
    """Dual ascent on ``log lambda``, one step per finished episode (the default of the on-policy Lagrangians)::

        log lambda <- clip(log lambda + lr * w * clip(g / saturation, -1, 1), log floor, log max)

    ``g = (J_c - d) / d`` with ``J_c`` the mean cost of the last :data:`EPISODE_WINDOW` finished episodes, ``w``
    the share of that window that ended since the last step (at most 1): each episode moves lambda once, however
    many iterations it spans and however many envs end together, so one ``lr`` means the same for 16 envs or 4096.

    - Multiplicative steps reach any scale (lambda* = 0.02 or 50) in ``ln(lambda* / lambda_0) / lr`` windows, as
      CQL's Adam on ``log alpha`` (Kumar et al. 2020); an additive step needs a summed violation of lambda* / lr.
    - ``g / saturation`` clipped to [-1, 1] bounds each step whatever the violation's size (OmniSafe's Adam on lambda
      moves it by about its learning rate per step; docs/constraint_satisfaction.md); at the default ``saturation``
      of 0.25 a violation of a quarter of the budget already takes a whole step: a run that hovers 3-10% over its
      budget otherwise moves lambda too little to close the gap before it ends.
    - ``floor`` stands for 0: a slack constraint's lambda decays to it (:attr:`FLOOR`, not an option: on
      standardised advantages 0.01 prices cost at a hundredth of reward, as good as none); ``max`` bounds a runaway where the policy
      cannot meet the budget (with standardised advantages lambda = 100 already prices cost 100 times reward), so
      that lambda comes back down in a few windows once it can.
    """

    per_episode = True
    state = ("log_value",)
    FLOOR = 0.01

    def __init__(
        self, cost_limit: float, lr: float, init: float, floor: float, maximum: float, scale: float, saturation: float
    ) -> None:
        if not 0 < floor <= init <= maximum:
            raise ValueError(f"the log dual needs 0 < floor <= init <= max, got {floor}, {init}, {maximum}")
        super().__init__(cost_limit, init, scale)
        self.lr, self.floor, self.maximum, self.saturation = lr, floor, maximum, saturation
        self.log_value = math.log(init)

    def _next_value(self, episode_cost: float, fresh: float = 1.0) -> float:
        g = max(-1.0, min(1.0, self.violation(episode_cost) / self.saturation))
        step = self.lr * min(1.0, max(0.0, fresh)) * g
        self.log_value = max(math.log(self.floor), min(math.log(self.maximum), self.log_value + step))
        return math.exp(self.log_value)


class PIDLagrangian(MultiplierController):
    """PID control of lambda (Stooke, Achiam, Abbeel, 2020, "Responsive Safety in Reinforcement
    Learning by PID Lagrangian Methods", Algorithm 2)::

        Delta   = J_c - d
        I       = clip(I + Ki * Delta, 0, lambda_max)          # anti-windup: I never below 0
        P       = EMA_p(Delta)                                  # p_ema_alpha = 0: the raw Delta
        D       = max(0, EMA_d(J_c)_k - EMA_d(J_c)_{k - d_delay})
        lambda  = clip(Kp * P + I + Kd * D, 0, lambda_max)

    ``init`` starts the integral, so ``Kp = Kd = 0``, ``Ki = lr`` is exactly :class:`DualAscent`.
    Clamping I at 0 is the paper's anti-windup (no negative integral banked over a feasible stretch),
    at ``lambda_max`` so it never winds up past lambda's range. Only a rise of the smoothed cost counts in
    D (falling cost never pushes lambda down faster than I); the first measurement fills the history.
    """

    state = ("integral", "delta_p", "cost_d")

    def __init__(
        self,
        cost_limit: float,
        kp: float,
        ki: float,
        kd: float,
        init: float = 0.0,
        p_ema_alpha: float = 0.0,
        d_ema_alpha: float = 0.0,
        d_delay: int = 1,
        lambda_max: float = math.inf,
        scale: float = 1.0,
    ) -> None:
        super().__init__(cost_limit, init, scale)
        if min(kp, ki, kd) < 0:
            raise ValueError(f"PID gains must be >= 0, got kp={kp}, ki={ki}, kd={kd}")
        if not (0.0 <= p_ema_alpha < 1.0 and 0.0 <= d_ema_alpha < 1.0):
            raise ValueError(f"EMA factors must be in [0, 1), got {p_ema_alpha}, {d_ema_alpha}")
        if d_delay < 1:
            raise ValueError(f"d_delay must be >= 1, got {d_delay}")
        if not init <= lambda_max:
            raise ValueError(f"algo.multiplier.init ({init}) must be <= algo.multiplier.max ({lambda_max})")
        self.kp, self.ki, self.kd = kp, ki, kd
        self.p_ema_alpha, self.d_ema_alpha, self.d_delay = p_ema_alpha, d_ema_alpha, d_delay
        self.maximum = lambda_max
        self.integral = float(init)
        self.delta_p: float | None = None  # EMA of J_c - d
        self.cost_d: float | None = None  # EMA of J_c
        self.history: deque[float] = deque(maxlen=d_delay)  # past EMA_d(J_c), oldest first

    def _next_value(self, episode_cost: float, fresh: float = 1.0) -> float:
        delta = self.violation(episode_cost)
        self.integral = min(self.maximum, max(0.0, self.integral + self.ki * delta))
        self.delta_p = delta if self.delta_p is None else _ema(self.delta_p, delta, self.p_ema_alpha)
        cost = episode_cost / self.scale  # the derivative's cost, in the violation's units
        self.cost_d = cost if self.cost_d is None else _ema(self.cost_d, cost, self.d_ema_alpha)
        if not self.history:
            self.history.extend([self.cost_d] * self.d_delay)
        derivative = max(0.0, self.cost_d - self.history[0])
        self.history.append(self.cost_d)
        return min(self.maximum, max(0.0, self.kp * self.delta_p + self.integral + self.kd * derivative))

    def state_dict(self) -> dict:
        return {**super().state_dict(), "history": list(self.history)}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.history = deque(state["history"], maxlen=self.d_delay)


class Multipliers:
    """One controller per constraint, controller k driven by ``J_c,k - d_k`` alone; ``make(d_k)`` builds it."""

    def __init__(self, make: Callable[[float], MultiplierController], cost_limits: Sequence[float]) -> None:
        self.controllers = [make(d) for d in cost_limits]

    @property
    def values(self) -> list[float]:
        return [c.value for c in self.controllers]

    def update(self, estimate: EpisodeCost | Sequence[float]) -> list[float]:
        """Step each constraint's controller on ``estimate`` (:func:`step`; a plain sequence: J_c,k per constraint,
        no window); returns the new lambdas."""
        if not isinstance(estimate, EpisodeCost):
            estimate = EpisodeCost(tuple(float(c) for c in estimate), math.nan, FINISHED)
        if len(estimate.costs) != len(self.controllers):
            raise ValueError(f"expected {len(self.controllers)} episode costs, got {len(estimate.costs)}")
        return [step(c, estimate, k) for k, c in enumerate(self.controllers)]

    def state_dict(self) -> dict:
        return {"constraints": [c.state_dict() for c in self.controllers]}

    def load_state_dict(self, state: dict) -> None:
        states = state["constraints"]
        if len(states) != len(self.controllers):
            raise ValueError(
                f"the saved multipliers are for {len(states)} constraints, this run has {len(self.controllers)}"
            )
        for c, s in zip(self.controllers, states):
            c.load_state_dict(s)


def step(controller: MultiplierController, estimate: EpisodeCost, k: int = 0) -> float:
    """``controller``'s step on constraint ``k`` of ``estimate``: a per-episode controller on the window's J_c,
    weighted by the share of the window that is new (no step before an episode has ended), any other on the
    iteration's J_c. Returns lambda."""
    if not controller.per_episode:
        return controller.update(estimate.costs[k])
    if estimate.window_costs is None or not estimate.fresh:
        return controller.value
    return controller.update(estimate.window_costs[k], estimate.fresh / EPISODE_WINDOW)


def logged_multiplier(values: list[float]) -> float | list[float]:
    """A multiplier as metrics.csv takes it: a number for one constraint, else a list of K."""
    return values[0] if len(values) == 1 else list(values)


def _ema(old: float, new: float, alpha: float) -> float:
    """Exponential moving average; ``alpha`` is the weight kept on the past."""
    return alpha * old + (1.0 - alpha) * new


# --- Last-iterate updates ----------------------------------------------------------------
# Plain dual ascent orbits the Lagrangian's saddle point: its guarantees hold for the average of the
# iterates, and where the optimum is a randomised policy the last policy swings over and under the
# budget. Each controller here damps that orbit its own way (``Pi``: the projection onto lambda >= 0).


class RegularizedDual(MultiplierController):
    """Regularised primal-dual (Ding, Wei, Zhang, Ribeiro, "Last-Iterate Convergent Policy
    Gradient Primal-Dual Methods for Constrained MDPs", NeurIPS 2023, arXiv 2306.11700, the dual
    step of their RPG-PD)::

        lambda <- Pi[(1 - lr * tau) lambda + lr * g]

    the dual step of the tau-regularised Lagrangian ``L + tau/2 lambda^2``, whose policy side carries an
    entropy bonus tau (ppo_lag adds it to entropy_coef). The saddle point becomes unique and the dynamics
    a contraction, at an O(tau) bias: at a fixed point ``g = tau lambda``."""

    def __init__(self, cost_limit: float, lr: float, tau: float, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        if not 0.0 <= lr * tau < 1.0:
            raise ValueError(f"algo.multiplier.lr * algo.multiplier.tau must be in [0, 1), got {lr} * {tau}")
        self.lr, self.tau = lr, tau

    def _next_value(self, episode_cost: float, fresh: float = 1.0) -> float:
        return max(0.0, (1.0 - self.lr * self.tau) * self.value + self.lr * self.violation(episode_cost))


class OptimisticDual(MultiplierController):
    """nuPI (Sohrabi, Ramirez, Zhang, Lacoste-Julien, Gallego-Posada, "On PI Controllers for
    Updating Lagrange Multipliers in Constrained Optimization", ICML 2024) with
    ``kappa_p = kappa_i = lr``::

        xi     = nu * xi_prev + (1 - nu) * g
        lambda <- Pi[lambda + lr * g + lr * (xi - xi_prev)]

    ``nu = 0`` is ReLOAD's optimistic step ``lambda <- Pi[lambda + lr (2 g_t - g_{t-1})]`` (Moskovitz et al.,
    "ReLOAD: Reinforcement Learning with Optimistic Ascent-Descent for Last-Iterate Convergence in
    Constrained MDPs", ICML 2023), which brakes lambda as soon as the violation turns. As cooper's nuPI,
    the first step takes ``xi_prev = xi``: plain dual ascent."""

    state = ("xi",)

    def __init__(self, cost_limit: float, lr: float, nu: float = 0.0, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        if not 0.0 <= nu < 1.0:
            raise ValueError(f"algo.multiplier.nu must be in [0, 1), got {nu}")
        self.lr, self.nu = lr, nu
        self.xi: float | None = None

    def _next_value(self, episode_cost: float, fresh: float = 1.0) -> float:
        g = self.violation(episode_cost)
        if self.xi is None:
            xi_prev = xi = g
        else:
            xi_prev = self.xi
            xi = self.nu * xi_prev + (1.0 - self.nu) * g
        self.xi = xi
        return max(0.0, self.value + self.lr * g + self.lr * (self.xi - xi_prev))


class AugmentedLagrangian(MultiplierController):
    """Augmented Lagrangian for an inequality constraint (Nocedal & Wright, "Numerical
    Optimization", 2nd ed., section 17.4, maximising ``J_r``): the primal objective is
    ``J_r - psi(g, lambda; rho)``, ``psi = rho/2 max(0, g + lambda/rho)^2 - lambda^2/(2 rho)``. One
    primal iteration stands in for the book's inner minimisation, so each iteration::

        lambda <- Pi[lambda + rho * g]          (the multiplier's update)
        value   = Pi[lambda + rho * g]          (d psi / d g at the current policy)

    ``value`` prices cost in the policy update: the penalty's slope, above the multiplier by ``rho g``
    while the budget is broken, 0 with slack; a proportional term on top of dual ascent.
    ``rho`` is ``algo.multiplier.lr``."""

    state = ("multiplier",)

    def __init__(self, cost_limit: float, rho: float, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        self.rho = rho
        self.multiplier = float(init)

    def _next_value(self, episode_cost: float, fresh: float = 1.0) -> float:
        step = self.rho * self.violation(episode_cost)
        self.multiplier = max(0.0, self.multiplier + step)
        return max(0.0, self.multiplier + step)


__all__ = [
    "EPISODE_WINDOW",
    "EpisodeCost",
    "EpisodeCostEstimate",
    "LogDual",
    "MultiplierController",
    "Multipliers",
    "step",
]
