"""The constraint's measured J_c and the multiplier that prices ``J_c - d``: the estimate of J_c every
constrained algorithm compares with its budget (:class:`EpisodeCostEstimate`), and the lambda controllers
that step on it, with their one options node ``algo.multiplier`` (built once per constraint).

``kind`` picks the update: ``dual`` (projected dual ascent, DualAscent), ``pid``
(PIDLagrangian), or a last-iterate update of the last-iterate section below (``regularized``,
``optimistic``, ``augmented``). ``lr``, ``init`` and ``scale`` are every kind's; the rest belong to
one kind each and are read by it alone; ``max`` clamps lambda from above for every kind. ppo_lag,
pid_lag (ppo_lag with ``kind: pid``), mappo_lag, trpo_lag, sac_lag, td3_lag, and FOCOPS and CUP
(their cost multiplier nu) take the node; each declares its own defaults (``configs/algo/<name>.yaml``
and the options class agree).

``scale`` picks the units of the violation the update steps on: ``none`` is ``J_c - d`` in the
cost's units, ``budget`` is ``(J_c - d) / d``. Budget normalisation was chosen over a running scale
of J_c or an adaptive optimiser (Adam on lambda, as OmniSafe): it keeps the update a plain function
of the measured cost (hand-checkable, nothing to warm up, the same fixed points: lambda still stops
moving exactly at ``J_c = d``), and it is the scale the constraint itself declares. Adam's
normalised step (about lr per iteration whatever the violation's size) also discards how far over
budget the policy is, and its momentum adds to the very orbit the last-iterate methods damp
(Sohrabi et al. 2024 show why momentum cannot remove it). docs/constraint_satisfaction.md has the
measurements.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque
from typing import Annotated, Callable, Literal, NamedTuple, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl.config.validation import (
    Field,
    NonNegativeFloat,
    PositiveFloat,
    PositiveInt,
    finite,
    options,
    require,
)
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import finished_episodes

# --- The measured J_c ------------------------------------------------------------------------
# The estimate of J_c, the expected undiscounted episode cost, one definition, so that
# PPO-Lagrangian's lambda, PID's error and CPO's constraint all read the same number. Per iteration:
# 1. episodes ended in this batch: the mean cost (and length) of those episodes;
# 2. none ended (episodes longer than a rollout, as on MuJoCo with 1000-step episodes and 256-step
#    rollouts): the mean of the last ``window`` episodes that ended in earlier batches (by default
#    one episode per env);
# 3. none has ended yet in the run: the mean cost so far of the running episodes, a lower bound.
# So the estimate exists at every iteration and a multiplier moves every iteration. With K costs it
# is per constraint, from the same episodes: ``costs`` has K entries.

FINISHED, WINDOW, RUNNING = "finished", "window", "running"


class EpisodeCost(NamedTuple):
    costs: tuple[float, ...]  # J_c estimate, one per constraint
    length: float  # mean episode length of the same episodes
    source: str  # FINISHED, WINDOW or RUNNING (the cases above)

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

    def update(self, batch: TensorDictBase) -> EpisodeCost:
        if self.window is None:
            self.window = batch.shape[0]
            self._recent = deque(self._recent, maxlen=self.window)
        eps = finished_episodes(batch)
        cost, length = eps["cost"], eps["length"]  # [E, K], [E]
        if length.numel():
            self._recent.extend((*c, n) for c, n in zip(cost.tolist(), length.tolist()))
            return EpisodeCost(_column_means(cost), length.mean().item(), FINISHED)
        if self._recent:
            recent = torch.tensor(list(self._recent), dtype=torch.float64)
            return EpisodeCost(_column_means(recent[:, :-1]), recent[:, -1].mean().item(), WINDOW)
        last = batch.get(keys.NEXT)[:, -1]
        return EpisodeCost(
            _column_means(last.get(keys.EPISODE_COST).float()),
            last.get(keys.EPISODE_LENGTH).float().mean().item(),
            RUNNING,
        )

    def state_dict(self) -> dict:
        return {"recent": list(self._recent), "window": self.window}

    def load_state_dict(self, state: dict) -> None:
        self.window = state.get("window", self.window)
        self._recent = deque((tuple(r) for r in state.get("recent", [])), maxlen=self.window)


def _column_means(x: torch.Tensor) -> tuple[float, ...]:
    """The mean of each column of ``[rows, K]``, each reduced as one column on its own."""
    return tuple(x[:, k].mean().item() for k in range(x.shape[1]))


# --- The controllers (the lambda update itself) ---------------------------------------------
# Controllers for the Lagrange multiplier lambda of a constrained objective.
#
# The Lagrangian of ``max J_r  s.t.  J_c <= d`` is ``J_r - lambda (J_c - d)``; its dual ascends on
# ``J_c - d``. Every controller takes the batch's measured episode cost explicitly, keeps
# lambda >= 0, and saves its state with ``state_dict``: :class:`MultiplierController` is the
# interface the Lagrangian algorithms program against.
#
# Every controller reads the violation ``(J_c - d) / scale``. ``scale = 1`` is the classical update
# in the cost's units; ``scale = d`` (``algo.multiplier.scale: budget``, algos/multiplier.py) makes it
# the relative violation, so that one step size means the same on a budget of 0.15 as on one of 25
# (docs/constraint_satisfaction.md). The last-iterate controllers live in algos/the last-iterate section below.


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


# --- Last-iterate updates ----------------------------------------------------------------
# Multiplier updates built to converge in the last iterate, not only on average.
#
# Plain projected dual ascent (DualAscent) orbits the saddle point of the Lagrangian: the
# classical guarantees hold for the average of the iterates, and when the optimum is a randomised
# policy the Lagrangian's maximisers at lambda* lie on both sides of the budget, so the last policy
# swings over and under it. Each controller here damps that orbit in a different way; all take one
# measured ``J_c`` per iteration through :meth:`MultiplierController.update` and read the violation
# ``g = (J_c - d) / scale`` (above). ``Pi`` is the projection onto ``lambda >= 0``.
#
# cooper-optim (PyPI) implements nuPI and the augmented Lagrangian for a differentiable constrained
# problem: its ConstrainedOptimizer takes the constraint as a tensor in the autograd graph of the
# primal loss and steps a torch optimizer on the multiplier. Here the constraint is one scalar
# measured from the batch's episodes once per iteration, and the primal step is PPO's clipped
# minibatch epochs, TRPO's line search or the off-policy actor's: no single Lagrangian backward pass
# exists for cooper to drive. Only its scalar recursions would fit, and those are the few lines
# below, whose state has to go into the run's checkpoint as plain numbers anyway.


class RegularizedDual(MultiplierController):
    """Regularised primal-dual (Ding, Wei, Zhang, Ribeiro, "Last-Iterate Convergent Policy
    Gradient Primal-Dual Methods for Constrained MDPs", NeurIPS 2023, arXiv 2306.11700, the dual
    step of their RPG-PD)::

        lambda <- Pi[(1 - lr * tau) lambda + lr * g]

    the gradient step on the dual of the tau-regularised Lagrangian ``L + tau/2 lambda^2``, whose
    policy side carries an entropy bonus tau (ppo_lag adds it to entropy_coef). The regulariser
    makes the saddle point unique and the dynamics a contraction, at the price of an O(tau) bias:
    at a fixed point ``g = tau lambda``, a violation of tau * lambda in the scaled units."""

    def __init__(self, cost_limit: float, lr: float, tau: float, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        if not 0.0 <= lr * tau < 1.0:
            raise ValueError(f"lambda_lr * lambda_tau must be in [0, 1), got {lr} * {tau}")
        self.lr, self.tau = lr, tau

    def _next_value(self, episode_cost: float) -> float:
        return max(0.0, (1.0 - self.lr * self.tau) * self.value + self.lr * self.violation(episode_cost))

    def state_dict(self) -> dict:
        return {"value": self.value}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])


class OptimisticDual(MultiplierController):
    """nuPI (Sohrabi, Ramirez, Zhang, Lacoste-Julien, Gallego-Posada, "On PI Controllers for
    Updating Lagrange Multipliers in Constrained Optimization", ICML 2024) with
    ``kappa_p = kappa_i = lr``::

        xi     = nu * xi_prev + (1 - nu) * g
        lambda <- Pi[lambda + lr * g + lr * (xi - xi_prev)]

    With ``nu = 0`` it is the optimistic gradient step ``lambda <- Pi[lambda + lr (2 g_t - g_{t-1})]``
    that ReLOAD applies to the multiplier (Moskovitz, O'Donoghue, Veeriah, Flennerhag, Singh,
    Zahavy, "ReLOAD: Reinforcement Learning with Optimistic Ascent-Descent for Last-Iterate
    Convergence in Constrained MDPs", ICML 2023, arXiv 2302.01275): the extra ``lr (g_t -
    g_{t-1})`` is a proportional term that brakes lambda as soon as the violation turns, before the
    policy has crossed the budget. As in cooper's nuPI, the first step has no predecessor: ``xi_prev``
    is taken equal to ``xi``, so the first step is plain dual ascent."""

    def __init__(self, cost_limit: float, lr: float, nu: float = 0.0, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        if not 0.0 <= nu < 1.0:
            raise ValueError(f"lambda_nu must be in [0, 1), got {nu}")
        self.lr, self.nu = lr, nu
        self.xi: float | None = None

    def _next_value(self, episode_cost: float) -> float:
        g = self.violation(episode_cost)
        if self.xi is None:
            xi_prev = xi = g
        else:
            xi_prev = self.xi
            xi = self.nu * xi_prev + (1.0 - self.nu) * g
        self.xi = xi
        return max(0.0, self.value + self.lr * g + self.lr * (self.xi - xi_prev))

    def state_dict(self) -> dict:
        return {"value": self.value, "xi": self.xi}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])
        self.xi = None if state.get("xi") is None else float(state["xi"])


class AugmentedLagrangian(MultiplierController):
    """Augmented Lagrangian for an inequality constraint (Nocedal & Wright, "Numerical
    Optimization", 2nd ed., section 17.4 on inequality constraints, maximising ``J_r``): the primal
    objective is ``J_r - psi(g, lambda; rho)`` with ``psi = rho/2 max(0, g + lambda/rho)^2 -
    lambda^2/(2 rho)``, and after each primal step ``lambda <- Pi[lambda + rho g]``.

    One primal iteration stands in for the book's inner minimisation, so each iteration, with g
    measured at the policy the last primal step produced::

        lambda <- Pi[lambda + rho * g]          (the multiplier's update)
        value   = Pi[lambda + rho * g]          (d psi / d g at the current policy)

    ``value`` is what the policy update prices cost with: the penalty's slope, which exceeds the
    multiplier by ``rho g`` while the budget is broken and falls to 0 with slack. Because the
    primal objective is frozen for the iteration, the quadratic acts through that slope alone:
    this is the penalty term's first-order effect, a proportional term on top of dual ascent.
    ``rho`` is ``algo.multiplier.lr``."""

    def __init__(self, cost_limit: float, rho: float, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        self.rho = rho
        self.multiplier = float(init)

    def _next_value(self, episode_cost: float) -> float:
        step = self.rho * self.violation(episode_cost)
        self.multiplier = max(0.0, self.multiplier + step)
        return max(0.0, self.multiplier + step)

    def state_dict(self) -> dict:
        return {"value": self.value, "multiplier": self.multiplier}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])
        self.multiplier = float(state["multiplier"])


# --- The options (algo.multiplier) and the controller they build -------------------------
Kind = Literal["dual", "pid", "regularized", "optimistic", "augmented"]
Scale = Literal["none", "budget"]
AdvantageScale = Literal["raw", "standardized"]  # ppo_lag.lagrangian_advantage
EMA = Annotated[float, finite(ge=0, lt=1)]  # a weight kept on the past, in [0, 1)


@options
class MultiplierConfig:
    """``algo.multiplier``: the update of lambda and its options (module docstring). Every kind
    reads the violation ``g = (J_c - d) / s`` (``s`` = d with ``scale: budget``, else 1)."""

    # dual: lambda <- max(0, lambda + lr g); pid: Stooke et al. 2020; regularized: Ding et al. 2023 (plus
    # an entropy bonus tau on an on-policy algorithm's policy); optimistic: nuPI / optimistic gradient;
    # augmented: augmented Lagrangian with rho = lr.
    kind: Kind = "dual"
    lr: PositiveFloat = 0.05  # the step of dual, regularized and optimistic; augmented's rho; pid: ki instead
    init: NonNegativeFloat = 0.0  # lambda at the start (pid: its integral's)
    scale: Scale = "budget"  # the violation's units: none: J_c - d; budget: (J_c - d) / d
    tau: NonNegativeFloat = 0.1  # regularized: tau, of the dual's regulariser (and ppo_lag's entropy bonus)
    nu: EMA = 0.0  # optimistic: the EMA weight of the violation (0: optimistic gradient)
    kp: NonNegativeFloat = 2.0  # pid: proportional gain
    ki: NonNegativeFloat = 0.1  # pid: integral gain (the dual-ascent step: kp = kd = 0 is dual with lr = ki)
    kd: NonNegativeFloat = 0.0  # pid: derivative gain, on the rise of the smoothed cost
    p_ema_alpha: EMA = 0.0  # pid: EMA weight on the past of the proportional term's violation
    d_ema_alpha: EMA = 0.0  # pid: EMA weight on the past of the cost the derivative differences
    d_delay: PositiveInt = 1  # pid: iterations between the two smoothed costs the derivative differences
    # An upper clamp on lambda, every kind (pid: on its integral too); .inf: none.
    max: Annotated[float, Field(gt=0, description="a positive number or .inf")] = math.inf

    def build(self, cost_limit: float) -> MultiplierController:
        """The controller of one constraint with budget ``cost_limit`` (the one constructor every
        Lagrangian algorithm calls, through :class:`~cmdp_rl.algos.multiplier.Multipliers`)."""
        controller = self._controller(cost_limit, violation_scale(cost_limit, self.scale))
        controller.maximum = self.max
        return controller

    def _controller(self, cost_limit: float, scale: float) -> MultiplierController:
        if self.kind == "pid":
            return PIDLagrangian(
                cost_limit,
                kp=self.kp,
                ki=self.ki,
                kd=self.kd,
                init=self.init,
                p_ema_alpha=self.p_ema_alpha,
                d_ema_alpha=self.d_ema_alpha,
                d_delay=self.d_delay,
                lambda_max=self.max,
                scale=scale,
            )
        if self.kind == "regularized":
            return RegularizedDual(cost_limit, self.lr, self.tau, self.init, scale)
        if self.kind == "optimistic":
            return OptimisticDual(cost_limit, self.lr, self.nu, self.init, scale)
        if self.kind == "augmented":
            return AugmentedLagrangian(cost_limit, self.lr, self.init, scale)
        return DualAscent(cost_limit, self.lr, self.init, scale)

    def check(self, prefix: str = "algo.multiplier") -> None:
        """Options that are valid alone but not together (a one-line ConfigError)."""
        if self.kind == "regularized":
            require(
                self.lr * self.tau < 1.0,
                f"{prefix}.tau",
                f"< 1 / {prefix}.lr = {1.0 / self.lr:g} (the dual step keeps (1 - lr tau) lambda >= 0)",
                self.tau,
            )
        if self.kind == "pid":
            gains = self.kp + self.ki + self.kd
            require(gains > 0, f"{prefix}.kp + {prefix}.ki + {prefix}.kd", "> 0 (some gain must act)", gains)
        require(self.init <= self.max, f"{prefix}.init", f"a number in [0, {prefix}.max]", self.init)


def violation_scale(cost_limit: float, scale: str) -> float:
    """The divisor of ``J_c - d``: 1, or the budget ``d`` itself. A zero budget has no scale of
    its own, so there the violation stays in the cost's units (the default must serve d = 0 too)."""
    return cost_limit if scale == "budget" and cost_limit > 0 else 1.0


__all__ = [
    "FINISHED",
    "RUNNING",
    "WINDOW",
    "AdvantageScale",
    "EpisodeCost",
    "EpisodeCostEstimate",
    "Kind",
    "MultiplierConfig",
    "Scale",
    "violation_scale",
]
