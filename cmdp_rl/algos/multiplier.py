"""The multiplier every Lagrangian algorithm shares: its options (``algo.multiplier``, one node) and the
controller they build, one per constraint.

``kind`` picks the update: ``dual`` (projected dual ascent, lagrange.DualAscent), ``pid``
(lagrange.PIDLagrangian), or a last-iterate update of last_iterate.py (``regularized``,
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
from typing import Annotated, Literal

from cmdp_rl.algos.lagrange import DualAscent, MultiplierController, PIDLagrangian
from cmdp_rl.algos.last_iterate import AugmentedLagrangian, OptimisticDual, RegularizedDual
from cmdp_rl.config.validation import (
    Field,
    NonNegativeFloat,
    PositiveFloat,
    PositiveInt,
    finite,
    options,
    require,
)

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
        Lagrangian algorithm calls, through :class:`~cmdp_rl.algos.lagrange.Multipliers`)."""
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


__all__ = ["AdvantageScale", "Kind", "MultiplierConfig", "Scale", "violation_scale"]
