"""What a run deploys (``deploy.policy``; the node's options in ``options.py``), kept beside its training:
the last iterate, the average of the actor's parameters over the last iterations (``average.py``) or a
mixture of snapshots of the actor (``mixture.py``). One per run, and one per agent of a population, each
on its own single-run agent, so both deploy by the same code; :func:`deploy_saved` puts the same policy
back from a checkpoint (evaluate, video, ``cmdp_rl.load``).
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

from cmdp_rl.config.run_config import RunConfig
from cmdp_rl.deploy.average import ParameterAverage, first_averaged_iteration
from cmdp_rl.deploy.mixture import IterateSnapshots
from cmdp_rl.deploy.selection import choose_weights
from cmdp_rl.policies.agent import Agent


class FinalPolicy:
    """``cfg.deploy.policy`` over a run of ``iterations``, continuing what ``saved`` (a checkpoint's
    entry) holds of it."""

    def __init__(self, cfg: RunConfig, iterations: int, saved: dict[str, Any] | None = None) -> None:
        self.cfg, self.iterations = cfg, iterations
        self.first = first_averaged_iteration(iterations, cfg.deploy.window)
        self.average = ParameterAverage() if cfg.deploy.policy == "average" else None
        previous = (saved or {}).get("policy_average")
        # (a resume that moved the window, e.g. more total_steps, restarts it)
        if self.average is not None and previous is not None and previous["first_iteration"] == self.first:
            self.average.load_state_dict(previous)
        self.mixture = None
        if cfg.deploy.policy == "mixture":
            self.mixture = IterateSnapshots(self.first, iterations, cfg.deploy.snapshots)
            if (saved or {}).get("policy_mixture") is not None:
                self.mixture.adopt(saved["policy_mixture"])

    @property
    def kept(self) -> ParameterAverage | IterateSnapshots | None:
        """What ``eval.json`` describes the deployed policy from (``trainer.complete_result``)."""
        return self.average or self.mixture

    def wants(self, iteration: int) -> bool:
        """Whether :meth:`after_update` reads the actor after this iteration's update."""
        return (self.average is not None and iteration >= self.first) or (
            self.mixture is not None and self.mixture.wants(iteration)
        )

    def after_update(self, agent: Agent, iteration: int, names: Sequence[str], echo: Callable[[str], None]) -> None:
        if self.average is not None and iteration >= self.first:
            self.average.update(agent.actor)
        if self.mixture is not None and self.mixture.wants(iteration):
            self.mixture.update(agent.actor, iteration)
            if iteration == self.iterations and self.cfg.deploy.weights == "feasible":  # before the last checkpoint
                echo(choose_weights(self.mixture, agent, self.cfg, names))

    def state_dict(self) -> dict[str, Any]:
        """The checkpoint's entries for it (none for the last iterate)."""
        out = {}
        if self.average is not None:
            out["policy_average"] = {"first_iteration": self.first, **self.average.state_dict()}
        if self.mixture is not None:
            out["policy_mixture"] = self.mixture.state_dict()
        return out

    def deploy(self, agent: Agent) -> None:
        """Put the deployed policy into ``agent`` (a checkpoint keeps the last iterate to resume from)."""
        if self.average is not None:
            self.average.apply(agent.actor)
        if self.mixture is not None:
            self.mixture.deploy(agent)


def deploy_saved(cfg: RunConfig, state: dict[str, Any], agent: Agent) -> None:
    """Put into ``agent`` (holding the checkpoint's last iterate) the policy the run deployed, from the
    checkpoint ``state``'s entries for it; a ValueError names what the checkpoint lacks."""
    if cfg.deploy.policy == "average":
        if "policy_average" not in state:
            raise ValueError("the checkpoint has no averaged policy, but the run has deploy.policy=average")
        average = ParameterAverage()
        average.load_state_dict(state["policy_average"])
        average.apply(agent.actor)
    if cfg.deploy.policy == "mixture":
        if "policy_mixture" not in state:
            raise ValueError("the checkpoint has no policy mixture, but the run has deploy.policy=mixture")
        mixture = IterateSnapshots(1, 1, 1)
        mixture.load_state_dict(state["policy_mixture"])
        mixture.deploy(agent)


__all__ = ["FinalPolicy", "deploy_saved"]
