"""What the trainer needs from an algorithm, and the failure every algorithm reports the same way."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Optional, Protocol, Sequence, Union, runtime_checkable

import torch
from tensordict import TensorDictBase
from torch import nn

from cmdp_rl.config.registry import declare_base
from cmdp_rl.config.validation import Bool, Discount, Field, PositiveFloat, finite, options, per_constraint, require

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig
    from cmdp_rl.envs.vector import VecEnv
    from cmdp_rl.policies.agent import Agent


Budget = Annotated[float, finite(ge=0)]
PerConstraint = Annotated[
    Union[Budget, list[Budget]], Field(description="a number >= 0 or a list of numbers >= 0, one per cost")
]


def single_constraint(cost_limit: float | Sequence[float], agent: Any, algo: str, reason: str) -> float:
    """The budget d of an algorithm that handles one constraint; an env with K > 1 costs is a config error
    naming ``reason`` and the toolkit's algorithms that take it (options with ``constraints`` and ``envs``
    None; a user's own registrations are not listed)."""
    from cmdp_rl.config.registry import component, names

    k, found = agent.num_costs, [(component("algo", n).options, n) for n in names("algo")]
    multi = [n for c, n in found if c.constraints is None and c.envs is None and c.__module__.startswith("cmdp_rl.")]
    require(
        k == 1,
        "algo",
        f"{', '.join(multi[:-1])} or {multi[-1]} for an env with {k} costs ({', '.join(agent.cost_names)}): {reason}",
        algo,
    )
    (d,) = per_constraint(cost_limit, "algo.cost_limit", agent.cost_names)
    return d


def require_minibatches(run: RunConfig, field: str, count: int) -> None:
    """``algo.<field>``: ``count`` minibatches must fit the batch of ``rollout_steps * env.num_envs`` units."""
    batch = run.rollout_steps * run.env.num_envs
    require(batch >= count, f"algo.{field}", f"at most rollout_steps * env.num_envs = {batch}", count)


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
    # The budget d on expected undiscounted episode cost (every run reports against it): one number, or K
    # in the env's cost order; None: the task's (the env options' budget()), filled in by config.validate.
    cost_limit: Annotated[
        Optional[Union[Budget, list[Budget]]],
        Field(description="a number >= 0 (the budget d), a list of such numbers (one per cost) or null (the task's)"),
    ] = None

    # The hooks below are all the toolkit asks of an algorithm's options besides its fields, with the
    # defaults of one that needs nothing special (docs/architecture.md, "Declared hooks").

    # How many constraints it takes: None, any K; 1, one (an env with K > 1 costs is refused).
    constraints: ClassVar[Optional[int]] = None
    # True: it compares costs in their own units with the budget, so normalize.cost=true is refused.
    reads_raw_cost: ClassVar[bool] = False
    # Options for a run of seconds in the tests every registered algorithm passes (test_registry_enrolment).
    tiny: ClassVar[dict[str, Any]] = {}
    # The envs it trains on, by name (None: any); another env is a one-line config error.
    envs: ClassVar[Optional[tuple[str, ...]]] = None
    # With ``envs``: the env options of its tiny test run, in place of TINY's Reach1D.
    tiny_env: ClassVar[dict[str, Any]] = {}
    # ``deploy.policy: auto``'s choice: "mixture" for a primal-dual method, whose last iterate orbits the saddle.
    deploys: ClassVar[str] = "last"

    def check(self, run: RunConfig) -> None:
        """Rules that relate this algorithm's options to the rest of the run: the envs it takes."""

    def resolve_auto(self, run: RunConfig) -> None:
        """Replace ``"auto"`` options by numbers from the run's batch shape (``run.rollout_steps`` is one)."""

    def auto_rollout_steps(self, run: RunConfig) -> Optional[int]:
        """``rollout_steps: auto`` for this algorithm; None: the run's rule (2048 / num_envs in [32, 256])."""
        return None

    @property
    def uniform_action_steps(self) -> int:
        """Env steps at the run's start on which the collector acts uniformly at random (a warm-up)."""
        return 0

    def describe_update(self) -> Optional[str]:
        """A few words on the update's shape for the run's start line (e.g. "10 x 8 minibatches")."""
        return None

    def wrap_env(self, env: VecEnv, evaluation: bool = False) -> VecEnv:
        """The env it trains (``evaluation=False``) or is evaluated on: ``env``, unless it changes the MDP (Sauté)."""
        return env

    def shape_agent(self, agent: Agent) -> Agent:
        """The networks it trains, from the agent ``policy=`` builds; ``make_agent(..., algo=...)`` calls it,
        so training and evaluation get the same networks without building the algorithm (off-policy: a
        squashed actor and Q-critics)."""
        return agent

    def observation_state(self, cost_names: tuple[str, ...]) -> Any:
        """For paths that step one plain env (video.py): a state carried beside the observation (Sauté's), or None."""
        return None


declare_base("algo", AlgoConfig)


class TrainingDiverged(RuntimeError):
    """A loss or parameter became NaN or infinite."""


def check_finite(**values: torch.Tensor | float) -> None:
    """Raise :class:`TrainingDiverged` naming the first non-finite value (of a tensor's: one per agent)."""
    for name, value in values.items():
        if isinstance(value, torch.Tensor) and value.numel() > 1:
            finite = torch.isfinite(value)
            if bool(finite.all()):
                continue
            value = value[~finite][0]
        x = value.item() if isinstance(value, torch.Tensor) else float(value)
        if not math.isfinite(x):
            raise TrainingDiverged(f"{name} is {x}: training diverged")


def check_parameters_finite(module: nn.Module) -> None:
    """A last step can leave a parameter infinite with every loss finite: keep it from a checkpoint."""
    params = list(module.named_parameters())
    finite = torch.stack([torch.isfinite(p).all() for _, p in params]).tolist()
    if not all(finite):
        name = next(n for (n, _), ok in zip(params, finite) if not ok)
        raise TrainingDiverged(f"parameter {name} is not finite after the update: training diverged")


@runtime_checkable
class Algorithm(Protocol):
    """An algorithm owns its networks' updates; it never touches the env. ``update`` takes one
    ``[num_envs, T]`` batch and returns ``lagrange_multiplier`` (the lambda in force, 0 if none, a list of
    K with K costs) and the names it declares in ``stats``: metrics.csv's columns."""

    name: str
    stats: tuple[str, ...]

    def update(self, batch: TensorDictBase) -> dict[str, float]: ...

    def state_dict(self) -> dict: ...

    def load_state_dict(self, state: dict) -> None: ...
