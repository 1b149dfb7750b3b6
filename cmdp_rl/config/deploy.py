"""The ``deploy:`` node (``RunConfig.deploy``): which policy a run hands back, read by ``deploy/final_policy.py``
and ``deploy/selection.py``; :func:`resolve_auto` turns ``policy: auto`` into what the run deploys."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from cmdp_rl.config.validation import AUTO, Field, NonNegativeFloat, PositiveInt, finite, options, require

RunConfig = Any  # cmdp_rl.config.run_config.RunConfig, which imports this module


@options
class DeployConfig:
    """``deploy:`` (configs/config.yaml documents each field): the last iterate, the parameter average
    (``average.py``) or a mixture of snapshots (``mixture.py``), weighted uniformly or by ``selection.py``."""

    policy: Literal["auto", "last", "average", "mixture"] = "auto"
    window: Annotated[float, finite(gt=0, le=1)] = 0.5
    snapshots: Annotated[int, Field(ge=1, le=64)] = 16
    weights: Literal["uniform", "feasible"] = "feasible"
    episodes: PositiveInt = 100  # weights=feasible: episodes each snapshot is valued on
    margin: NonNegativeFloat = 3.0  # weights=feasible: standard errors added to each snapshot's costs

    def check(self, run: RunConfig) -> None:
        """Rules that relate the deployed policy to the rest of the run."""
        require(
            self.policy != "mixture" or run.policy.name == "mlp",
            "deploy.policy",
            f"last or average with policy={run.policy.name} (a mixture draws among memoryless actors: policy=mlp)",
            self.policy,
        )


# The snapshot valuation's price where episodes are not declared cheap: at most this share of the run's env
# steps, on at least MIN_VALUED_EPISODES episodes per snapshot (fewer snapshots rather than fewer episodes: a
# cost measured on a handful has a standard error of the budget's order on the navigation tasks, and the
# margin then rules every snapshot out). A run too short for one such snapshot deploys its last iterate.
VALUATION_SHARE = 0.1
MIN_VALUED_EPISODES = 20


def valuation_plan(cfg: RunConfig) -> tuple[int, int] | None:
    """(snapshots, episodes each) of ``auto``'s mixture within :data:`VALUATION_SHARE` of ``total_steps`` where
    episodes are not declared cheap; None where that buys no snapshot :data:`MIN_VALUED_EPISODES` episodes."""
    steps = cfg.env.episode_steps()
    if not steps:
        return None
    episodes = int(VALUATION_SHARE * cfg.total_steps // steps)
    size = min(cfg.deploy.snapshots, episodes // MIN_VALUED_EPISODES)
    return (size, min(cfg.deploy.episodes, episodes // size)) if size >= 1 else None


def resolve_auto(cfg: RunConfig) -> None:
    """``deploy.policy: auto`` becomes ``mixture`` for a primal-dual algorithm with a memoryless policy where the
    env's episodes are cheap to value or :func:`valuation_plan` buys a valuation (setting it), else ``last``."""
    deploy = cfg.deploy
    if deploy.policy != AUTO:
        return
    mixture = cfg.algo.deploys == "mixture" and cfg.policy.name == "mlp"
    plan = None if cfg.env.values_snapshots else valuation_plan(cfg)
    if mixture and not cfg.env.values_snapshots and plan is not None:
        deploy.snapshots, deploy.episodes = plan
    deploy.policy = "mixture" if mixture and (cfg.env.values_snapshots or plan is not None) else "last"
