"""What a run (or population agent) deploys, kept beside its training: the last iterate, the parameter average
(``average.py``) or a mixture of snapshots (``mixture.py``); :func:`deploy_saved` puts it back from a checkpoint."""

from __future__ import annotations

from typing import Any, Callable, Sequence

from cmdp_rl.config.run_config import RunConfig
from cmdp_rl.deploy.average import ParameterAverage, first_averaged_iteration
from cmdp_rl.deploy.mixture import IterateSnapshots
from cmdp_rl.deploy.selection import choose_weights
from cmdp_rl.policies.agent import Agent

# The checkpoint's entry of each deployed policy that keeps something, and what the entry holds.
ENTRIES = {"average": ("policy_average", "averaged policy"), "mixture": ("policy_mixture", "policy mixture")}


class FinalPolicy:
    """``cfg.deploy.policy`` over a run of ``iterations``, continuing a checkpoint entry's ``saved``."""

    def __init__(self, cfg: RunConfig, iterations: int, saved: dict[str, Any] | None = None) -> None:
        self.cfg, self.iterations = cfg, iterations
        first = first_averaged_iteration(iterations, cfg.deploy.window)
        previous = (saved or {}).get(ENTRIES.get(cfg.deploy.policy, ("",))[0])
        self.kept: ParameterAverage | IterateSnapshots | None = None  # what eval.json describes it from
        if cfg.deploy.policy == "average":
            self.kept = ParameterAverage(first)
            # (a resume that moved the window, e.g. more total_steps, restarts it)
            if previous is not None and previous["first_iteration"] == first:
                self.kept.load_state_dict(previous)
        elif cfg.deploy.policy == "mixture":
            self.kept = IterateSnapshots(first, iterations, cfg.deploy.snapshots)
            if previous is not None:
                self.kept.adopt(previous)

    def wants(self, iteration: int) -> bool:
        """Whether :meth:`after_update` reads the actor after this iteration's update."""
        return self.kept is not None and self.kept.wants(iteration)

    def after_update(self, agent: Agent, iteration: int, names: Sequence[str], echo: Callable[[str], None]) -> None:
        if not self.wants(iteration):
            return
        self.kept.update(agent.actor, iteration)
        last = iteration == self.iterations and self.cfg.deploy.weights == "feasible"  # before the last checkpoint
        if isinstance(self.kept, IterateSnapshots) and last:
            echo(choose_weights(self.kept, agent, self.cfg, names))

    def state_dict(self) -> dict[str, Any]:
        """The checkpoint's entries for it (none for the last iterate)."""
        return {} if self.kept is None else {ENTRIES[self.cfg.deploy.policy][0]: self.kept.state_dict()}

    def deploy(self, agent: Agent) -> None:
        """Put the deployed policy into ``agent`` (a checkpoint keeps the last iterate to resume from)."""
        if self.kept is not None:
            self.kept.deploy(agent)


def deploy_saved(cfg: RunConfig, state: dict[str, Any], agent: Agent) -> None:
    """Put into ``agent`` (the checkpoint's last iterate) the policy the run deployed, from ``state``."""
    if cfg.deploy.policy not in ENTRIES:
        return
    key, what = ENTRIES[cfg.deploy.policy]
    if key not in state:
        raise ValueError(f"the checkpoint has no {what}, but the run has deploy.policy={cfg.deploy.policy}")
    kept = ParameterAverage() if cfg.deploy.policy == "average" else IterateSnapshots(1, 1, 1)
    kept.load_state_dict(state[key])
    kept.deploy(agent)
