"""What the trainer needs from an algorithm, and the failure every algorithm reports the same way."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Any, Optional, Protocol, Sequence, Union, runtime_checkable

import torch
from tensordict import TensorDictBase
from torch import nn

from cmdp_rl.validation import Bool, Discount, Field, PositiveFloat, finite, options, require

if TYPE_CHECKING:
    from cmdp_rl.config import RunConfig


Budget = Annotated[float, finite(ge=0)]
# A number (the same for every constraint) or one number per constraint.
PerConstraint = Annotated[
    Union[Budget, list[Budget]], Field(description="a number >= 0 or a list of numbers >= 0, one per cost")
]


def per_constraint(value: float | Sequence[float], field: str, cost_names: Sequence[str]) -> list[float]:
    """``value`` (a number, or a list of K numbers) as K numbers, one per cost of ``cost_names``; a
    list of another length is a config error naming ``field`` and K. Only the env tells K, so this
    runs when the algorithm is built on the agent, before the run writes anything."""
    k = len(cost_names)
    if isinstance(value, (int, float)):
        return [float(value)] * k
    values = list(value)
    require(
        len(values) == k,
        field,
        f"a number or a list of {k} numbers, one per cost of the env ({', '.join(cost_names)})",
        values,
    )
    return [float(v) for v in values]


# The algorithms that take an env with K > 1 costs (one multiplier or penalty per constraint).
MULTI_CONSTRAINT = ("ppo", "penalty", "ppo_lag", "pid_lag", "trpo_lag", "saute", "sac", "sac_lag", "td3", "td3_lag")


def single_constraint(cost_limit: float | Sequence[float], agent: Any, algo: str, reason: str) -> float:
    """The budget d of an algorithm that handles one constraint (``agent.num_costs`` must be 1);
    an env with K > 1 costs is a config error naming the algorithms that take it and ``reason``."""
    k = agent.num_costs
    require(
        k == 1,
        "algo",
        f"{', '.join(MULTI_CONSTRAINT[:-1])} or {MULTI_CONSTRAINT[-1]} for an env with {k} "
        f"costs ({', '.join(agent.cost_names)}): {reason}",
        algo,
    )
    (d,) = per_constraint(cost_limit, "algo.cost_limit", agent.cost_names)
    return d


@options
class AlgoConfig:
    """Options every algorithm shares: discounts, GAE, the critics, the budget."""

    name: str = "ppo"
    critic_lr: PositiveFloat = 1e-3
    gamma: Discount = 0.99
    gae_lambda: Annotated[float, finite(ge=0, le=1)] = 0.95
    cost_gamma: Discount = 0.99
    max_grad_norm: Annotated[float, Field(gt=0)] = 0.5
    normalize_advantage: Bool = True
    # The budget d on expected undiscounted episode cost. Only constrained algorithms act on it;
    # every run reports against it. With K costs: one number for every constraint, or a list of K
    # budgets in the env's cost order (per_constraint). None: the task's budget (the env options'
    # budget()), filled in by config.validate before anything is built.
    cost_limit: Annotated[
        Optional[Union[Budget, list[Budget]]],
        Field(description="a number >= 0 (the budget d), a list of such numbers (one per cost) or null (the task's)"),
    ] = None

    def check(self, run: RunConfig) -> None:
        """Rules that relate this algorithm's options to the rest of the run (none here)."""


class TrainingDiverged(RuntimeError):
    """A loss or parameter became NaN or infinite."""


def check_finite(**values: torch.Tensor | float) -> None:
    """Raise :class:`TrainingDiverged` naming the first non-finite value."""
    for name, value in values.items():
        x = value.item() if isinstance(value, torch.Tensor) else float(value)
        if not math.isfinite(x):
            raise TrainingDiverged(f"{name} is {x}: training diverged")


def check_parameters_finite(module: nn.Module) -> None:
    """A last step can leave a parameter infinite with every loss finite: never let such a network
    reach a checkpoint. One check for all parameters, one host sync."""
    params = list(module.named_parameters())
    finite = torch.stack([torch.isfinite(p).all() for _, p in params]).tolist()
    if not all(finite):
        name = next(n for (n, _), ok in zip(params, finite) if not ok)
        raise TrainingDiverged(f"parameter {name} is not finite after the update: training diverged")


@runtime_checkable
class Algorithm(Protocol):
    """An algorithm owns its networks' updates; it never touches the env.

    ``update`` takes one ``[num_envs, T]`` batch from the collector and returns scalars to log:
    ``lagrange_multiplier`` (the lambda in force; 0 if none; with K > 1 costs a list of K, one per
    constraint, which metrics.csv spreads over one column per cost) and the names it declares in
    ``stats``, which become metrics.csv's columns (``metrics.columns``).
    """

    name: str
    stats: tuple[str, ...]

    def update(self, batch: TensorDictBase) -> dict[str, float]: ...

    def state_dict(self) -> dict: ...

    def load_state_dict(self, state: dict) -> None: ...
