"""What the training loop trains (:class:`Kernel`): the members' agents and algorithms, the env they step, the
collector, the update, and what a checkpoint keeps of them. A run's is :class:`AgentKernel` (one agent, P = 1,
its own networks and torch's Adam); a population's is ``population.stacked_kernel.StackedKernel`` (P agents as
one tensor program). The loop (``run/loop.py``) and the run's opening and end are written once against it."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol, Sequence, runtime_checkable

from tensordict import TensorDictBase

from cmdp_rl.algos.base import Algorithm
from cmdp_rl.config.run_config import RunConfig
from cmdp_rl.envs import VecEnv
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.run.migrations import migrate
from cmdp_rl.run.rng import load_rng_state, rng_state


@runtime_checkable
class Kernel(Protocol):
    """The members a training loop trains (a run's one agent, a population's P), as the loop, the opening and
    the end of a run ask for them. ``agents[k]`` and ``algos[k]`` are member k's single-run objects: what its
    checkpoint entry, its deployed policy and its evaluation read (after :meth:`sync_agents`)."""

    @property
    def env(self) -> VecEnv: ...

    @property
    def agents(self) -> Sequence[Agent]: ...

    @property
    def algos(self) -> Sequence[Algorithm]: ...

    @property
    def collector(self) -> Collector: ...

    @property
    def per_iter(self) -> int:
        """Env steps per member per iteration."""
        ...

    def restore(self, state: dict[str, Any], saved_cfgs: list[dict]) -> dict[str, Any]:
        """A resume's checkpoint ``state`` into the members (``saved_cfgs``: their config.yaml as written);
        returns it in the current layout."""
        ...

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        """Every member's update on the batch; each member's logged statistics."""
        ...

    def cost_totals(self, batch: TensorDictBase | None = None) -> list[list[float]]:
        """Each member's costs collected so far, ``batch``'s included when given."""
        ...

    def rng(self) -> dict[str, Any]:
        """The random state a checkpoint keeps."""
        ...

    def sync_agents(self) -> None:
        """Each member's networks and optimiser state into its algorithm object (its ``state_dict`` then its
        single run's): a checkpoint's entries and the deployed policy read them there."""
        ...

    def sync_actors(self) -> None:
        """Each member's actor into its agent, for the deployed policy to read after an update."""
        ...

    def checkpoint_extras(self) -> dict[str, Any]:
        """What a checkpoint keeps besides the members' entries and the shared state."""
        ...

    def after_checkpoint(self, path: Path) -> None:
        """After a checkpoint was written to ``path``."""
        ...


class AgentKernel:
    """A run's kernel (P = 1): its own networks and torch's Adam (``algo.update``), its collector's seed and
    warm-up, reward and observation scaling; the global random state."""

    def __init__(self, cfg: RunConfig, env: VecEnv, agent: Agent, algo: Algorithm) -> None:
        self.env, self.agents, self.algos = env, [agent], [algo]
        # An off-policy algorithm's options may ask for uniformly random actions during its warm-up.
        self.collector = Collector(
            env, agent, cfg.rollout_steps, seed=cfg.seed, uniform_steps=cfg.algo.uniform_action_steps
        )
        self.per_iter = int(cfg.rollout_steps) * env.num_envs  # rollout_steps: "auto" is resolved by now

    def restore(self, state: dict[str, Any], saved_cfgs: list[dict]) -> dict[str, Any]:
        state = migrate(state, self.agents[0])  # an older format's layout (a trusted file) in the current one
        restore(state, self.algos, self.collector)
        load_rng_state(state["rng"])
        return state

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        normalizers = self.agents[0].normalizers
        normalizers.scale_batch(batch)  # reward/cost scaling, if on (episode sums stay raw)
        stats = self.algos[0].update(batch)
        normalizers.update_observation_stats(batch)  # after the update: see normalization.py
        return [stats]

    def cost_totals(self, batch: TensorDictBase | None = None) -> list[list[float]]:
        return [self.collector.total_costs]

    def rng(self) -> dict[str, Any]:
        return rng_state()

    # The agent is the algorithm's own: nothing to copy, nothing else to keep.
    def sync_agents(self) -> None:
        pass

    def sync_actors(self) -> None:
        pass

    def checkpoint_extras(self) -> dict[str, Any]:
        return {}

    def after_checkpoint(self, path: Path) -> None:
        pass


def restore(state: dict[str, Any], algos: Sequence[Any], collector: Collector) -> None:
    """A resume's checkpoint into each member's algorithm (from its entry) and into the collector."""
    for algo, entry in zip(algos, state["members"]):
        algo.load_state_dict(entry["algo_state"])
    collector.load_state_dict(state["collector"])
