"""The multiplier options the Lagrangian algorithms share, and the controller they build.

``multiplier`` picks the update (lagrange.py, last_iterate.py); ``lambda_scale`` picks the units of
the violation it steps on: ``none`` is ``J_c - d`` in the cost's units, ``budget`` is
``(J_c - d) / d``. Budget normalisation was chosen over a running scale of J_c or an adaptive
optimiser (Adam on lambda, as OmniSafe): it keeps the update a plain function of the measured
cost (hand-checkable, nothing to warm up, the same fixed points: lambda still stops moving exactly
at ``J_c = d``), and it is the scale the constraint itself declares. Adam's normalised step
(about lr per iteration whatever the violation's size) also discards how far over budget the
policy is, and its momentum adds to the very orbit the last-iterate methods damp
(Sohrabi et al. 2024 show why momentum cannot remove it). docs/constraint_satisfaction.md has the measurements.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

from cmdp_rl.algos.lagrange import DualAscent, MultiplierController
from cmdp_rl.algos.last_iterate import AugmentedLagrangian, OptimisticDual, RegularizedDual
from cmdp_rl.config.validation import NonNegativeFloat, finite, require

Update = Literal["dual", "regularized", "optimistic", "augmented"]
Scale = Literal["none", "budget"]
AdvantageScale = Literal["raw", "standardized"]  # ppo_lag.lagrangian_advantage


@dataclass
class MultiplierFields:
    """Mixed into the options of ppo_lag and trpo_lag (lambda_init and lambda_lr are theirs)."""

    # dual: projected dual ascent; regularized: Ding et al. 2023 (plus an entropy bonus tau on the
    # policy); optimistic: nuPI / optimistic gradient; augmented: augmented Lagrangian (rho = lambda_lr).
    multiplier: Update = "dual"
    lambda_scale: Scale = "budget"  # the violation's units: none: J_c - d; budget: (J_c - d) / d
    advantage_scale: AdvantageScale = "raw"  # lambda weighs: raw: A_r and A_c; standardized: each standardised
    lambda_tau: NonNegativeFloat = 0.1  # regularized: tau, of the dual's regulariser and the entropy bonus
    lambda_nu: Annotated[float, finite(ge=0, lt=1)] = (
        0.0  # optimistic: nu, the EMA of the violation (0: optimistic gradient)
    )


def violation_scale(cost_limit: float, lambda_scale: str) -> float:
    """The divisor of ``J_c - d``: 1, or the budget ``d`` itself. A zero budget has no scale of
    its own, so there the violation stays in the cost's units (the default must serve d = 0 too)."""
    return cost_limit if lambda_scale == "budget" and cost_limit > 0 else 1.0


def make_controller(cfg: Any, cost_limit: float, lr: float, init: float) -> MultiplierController:
    """The controller ``cfg.multiplier`` names, on budget ``cost_limit`` (fields of
    :class:`MultiplierFields`)."""
    scale = violation_scale(cost_limit, cfg.lambda_scale)
    if cfg.multiplier == "regularized":
        return RegularizedDual(cost_limit, lr, cfg.lambda_tau, init, scale)
    if cfg.multiplier == "optimistic":
        return OptimisticDual(cost_limit, lr, cfg.lambda_nu, init, scale)
    if cfg.multiplier == "augmented":
        return AugmentedLagrangian(cost_limit, lr, init, scale)
    return DualAscent(cost_limit, lr, init, scale)


def check_multiplier(cfg: Any, lr: float) -> None:
    """Options that are valid alone but not together (a one-line ConfigError)."""
    if cfg.multiplier == "regularized":
        require(
            lr * cfg.lambda_tau < 1.0,
            "algo.lambda_tau",
            f"< 1 / algo.lambda_lr = {1.0 / lr:g} (the dual step keeps (1 - lr tau) lambda >= 0)",
            cfg.lambda_tau,
        )
