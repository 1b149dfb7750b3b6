"""Controllers for the Lagrange multiplier lambda of a constrained objective.

The Lagrangian of ``max J_r  s.t.  J_c <= d`` is ``J_r - lambda (J_c - d)``; its dual ascends on
``J_c - d``. Every controller takes the batch's measured episode cost explicitly, keeps
lambda >= 0, and saves its state with ``state_dict``: :class:`MultiplierController` is the
interface the Lagrangian algorithms program against.

Every controller reads the violation ``(J_c - d) / scale``. ``scale = 1`` is the classical update
in the cost's units; ``scale = d`` (``algo.multiplier.scale: budget``, algos/multiplier.py) makes it
the relative violation, so that one step size means the same on a budget of 0.15 as on one of 25
(docs/constraint_satisfaction.md). The last-iterate controllers live in algos/last_iterate.py.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque
from typing import Callable, Sequence


class MultiplierController(ABC):
    """Sets lambda >= 0 from one measurement of the mean undiscounted episode cost ``J_c`` per
    iteration. ``value`` is the lambda in force."""

    # An upper clamp on lambda (``algo.multiplier.max``; FOCOPS's clamp on nu): the update is projected onto
    # [0, maximum]. A class attribute, set by ``MultiplierConfig.build``: infinite, it changes nothing.
    maximum: float = math.inf

    def __init__(self, cost_limit: float, init: float = 0.0, scale: float = 1.0) -> None:
        if init < 0:
            raise ValueError(f"lambda_init must be >= 0, got {init}")
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"the violation's scale must be a positive number, got {scale}")
        self.cost_limit = cost_limit
        self.scale = float(scale)
        self.value = float(init)

    def violation(self, episode_cost: float) -> float:
        """``(J_c - d) / scale``: the dual gradient the controllers step on."""
        return (episode_cost - self.cost_limit) / self.scale

    def update(self, episode_cost: float) -> float:
        """Take in ``J_c`` (finite), update and return the new lambda."""
        if not math.isfinite(episode_cost):
            raise ValueError(f"episode_cost must be finite, got {episode_cost}")
        self.value = min(self.maximum, self._next_value(float(episode_cost)))
        assert self.value >= 0.0
        return self.value

    @abstractmethod
    def _next_value(self, episode_cost: float) -> float:
        """The new lambda (>= 0) after measuring ``episode_cost``."""

    @abstractmethod
    def state_dict(self) -> dict: ...

    @abstractmethod
    def load_state_dict(self, state: dict) -> None: ...


class DualAscent(MultiplierController):
    """Projected gradient ascent on the dual: ``lambda <- max(0, lambda + lr * (J_c - d))``.

    As in PPO-Lagrangian (Ray, Achiam, Amodei, "Benchmarking Safe Exploration in Deep RL", 2019);
    the primal-dual (PDO) update of Achiam et al. 2017, "Constrained Policy Optimization", eq. 16.
    """

    def __init__(self, cost_limit: float, lr: float, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        self.lr = lr

    def _next_value(self, episode_cost: float) -> float:
        return max(0.0, self.value + self.lr * self.violation(episode_cost))

    def state_dict(self) -> dict:
        return {"value": self.value}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])


class PIDLagrangian(MultiplierController):
    """PID control of lambda (Stooke, Achiam, Abbeel, 2020, "Responsive Safety in Reinforcement
    Learning by PID Lagrangian Methods", Algorithm 2)::

        Delta   = J_c - d
        I       = clip(I + Ki * Delta, 0, lambda_max)          # anti-windup: I never below 0
        P       = EMA_p(Delta)                                  # p_ema_alpha = 0: the raw Delta
        D       = max(0, EMA_d(J_c)_k - EMA_d(J_c)_{k - d_delay})
        lambda  = clip(Kp * P + I + Kd * D, 0, lambda_max)

    Dual ascent is the integral term alone: the integral here accumulates ``Ki * Delta`` (not
    ``Delta``), so ``lambda_init`` is its starting value and a PID with ``Kp = Kd = 0`` and
    ``Ki = lr`` produces exactly :class:`DualAscent`'s sequence. Clamping the integral at 0 is the
    paper's anti-windup: without it a long feasible stretch would bank negative integral that must
    be paid back, in cost, before lambda can rise again. Clamping it at ``lambda_max`` as well
    stops it winding up beyond what lambda may take. The paper keeps only the positive part of the
    derivative, so that falling cost never pushes lambda down faster than the integral does; it is
    taken on an exponentially smoothed cost, since single-batch episode costs are noisy.
    The first measurement has no predecessor: the history is filled with it, so D starts at 0.
    """

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
            raise ValueError(f"lambda_init ({init}) must be <= lambda_max ({lambda_max})")
        self.kp, self.ki, self.kd = kp, ki, kd
        self.p_ema_alpha, self.d_ema_alpha, self.d_delay = p_ema_alpha, d_ema_alpha, d_delay
        self.lambda_max = lambda_max
        self.integral = float(init)
        self.delta_p: float | None = None  # EMA of J_c - d
        self.cost_d: float | None = None  # EMA of J_c
        self.history: deque[float] = deque(maxlen=d_delay)  # past EMA_d(J_c), oldest first
        self.terms = {"p": 0.0, "i": self.integral, "d": 0.0}  # the last update's contributions

    def _next_value(self, episode_cost: float) -> float:
        delta = self.violation(episode_cost)
        self.integral = min(self.lambda_max, max(0.0, self.integral + self.ki * delta))
        self.delta_p = delta if self.delta_p is None else _ema(self.delta_p, delta, self.p_ema_alpha)
        cost = episode_cost / self.scale  # the derivative's cost, in the violation's units
        self.cost_d = cost if self.cost_d is None else _ema(self.cost_d, cost, self.d_ema_alpha)
        if not self.history:
            self.history.extend([self.cost_d] * self.d_delay)
        derivative = max(0.0, self.cost_d - self.history[0])
        self.history.append(self.cost_d)
        self.terms = {"p": self.kp * self.delta_p, "i": self.integral, "d": self.kd * derivative}
        return min(self.lambda_max, max(0.0, sum(self.terms.values())))

    def state_dict(self) -> dict:
        return {
            "value": self.value,
            "integral": self.integral,
            "delta_p": self.delta_p,
            "cost_d": self.cost_d,
            "history": list(self.history),
        }

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])
        self.integral = float(state["integral"])
        self.delta_p, self.cost_d = state["delta_p"], state["cost_d"]
        self.history = deque(state["history"], maxlen=self.d_delay)


class Multipliers:
    """One multiplier per constraint: K independent controllers, controller k driven by J_c,k - d_k
    alone. The Lagrangian of ``max J_r s.t. J_c,k <= d_k (k < K)`` is ``J_r - sum_k lambda_k
    (J_c,k - d_k)``; its dual gradient in lambda_k is ``J_c,k - d_k``, so each multiplier ascends
    (or is PID-controlled) on its own constraint's violation, as one would for K = 1.

    ``make(d_k)`` builds constraint k's controller."""

    def __init__(self, make: Callable[[float], MultiplierController], cost_limits: Sequence[float]) -> None:
        self.controllers = [make(d) for d in cost_limits]

    @property
    def values(self) -> list[float]:
        return [c.value for c in self.controllers]

    def update(self, episode_costs: Sequence[float]) -> list[float]:
        """Take in ``J_c,k`` per constraint; returns the new lambdas."""
        if len(episode_costs) != len(self.controllers):
            raise ValueError(f"expected {len(self.controllers)} episode costs, got {len(episode_costs)}")
        return [c.update(j) for c, j in zip(self.controllers, episode_costs)]

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


def _ema(old: float, new: float, alpha: float) -> float:
    """Exponential moving average; ``alpha`` is the weight kept on the past."""
    return alpha * old + (1.0 - alpha) * new
