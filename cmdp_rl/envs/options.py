"""Options every env shares, whatever its backend; each env's options class extends
:class:`EnvOptions`, and what it declares here is all the rest of the toolkit asks of an env's
options (docs/architecture.md lists these hooks)."""

from __future__ import annotations

from typing import Any, ClassVar, Optional, Sequence

from cmdp_rl.config.registry import declare_base
from cmdp_rl.config.validation import Bool, options

# The budget d of a task that states none (Reach1D's: one crossing of the wall per episode).
DEFAULT_BUDGET = 1.0
# Safety-Gymnasium's tasks, and the velocity tasks built like them, are reported with d = 25 cost per
# 1000-step episode (Ray, Achiam, Amodei 2019; Ji et al. 2023, "Safety-Gymnasium"; OmniSafe).
SAFETY_GYM_BUDGET = 25.0


@options
class EnvOptions:
    """``allow_negative_cost``: accept negative costs, which the env contract otherwise refuses (a
    CMDP's costs are >= 0: docs/guide/env_contract.md)."""

    allow_negative_cost: Bool = False
    # Evaluation reports the fraction of episodes that terminated under this name (e.g. a goal
    # reached); None: the env's termination means nothing worth reporting.
    termination_metric: ClassVar[Optional[str]] = None
    # Whether a run's snapshots may be valued on deploy.snapshots x deploy.episodes episodes whatever that costs
    # (cheap episodes of a batched env); else the valuation is held to a share of the run's steps (config/deploy.py).
    values_snapshots: ClassVar[bool] = False

    def check(self, run: Any) -> None:
        """Rules that relate this env's options to the rest of the run (none here)."""

    def env_id(self) -> str:
        """How the env contract's messages name this env."""
        return getattr(self, "id", "") or getattr(self, "name", "env")

    def budget(self) -> float | list[float]:
        """The task's budget d on expected undiscounted episode cost: one number for every
        constraint, or one per cost in the env's cost order. ``algo.cost_limit`` defaults to it
        (``config.resolve_budget``); a value given for ``algo.cost_limit`` wins."""
        return DEFAULT_BUDGET

    def episode_steps(self) -> int | None:
        """The longest an episode runs (its time limit), where the options say; None: unknown."""
        return getattr(self, "max_steps", None) or None

    def valuation_options(self) -> EnvOptions:
        """The options the snapshot valuation (``deploy.selection``) builds its env from: the same
        CMDP, on a batched backend where this env has one (these options themselves here)."""
        return self

    def population_env(
        self, env_cfgs: Sequence[Any], num_envs: int, seeds: Sequence[int], device: Any, evaluation: bool
    ) -> Any:
        """The envs of P agents (``env_cfgs``, these options first), ``num_envs`` each, agent i's seeded
        with ``seeds[i]``, as one batched env whose agent i's rows step exactly as its single run's envs;
        None: the population steps each agent's own env in turn (``population.envs.AgentEnvs``)."""
        return None


declare_base("env", EnvOptions)
