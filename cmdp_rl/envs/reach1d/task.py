"""Reach1D as a component (``env=reach1d``): its options, checked before anything is built, and
the backend that runs them: the seed-exact gymnasium env (``env.py``) in a synchronous vector
env, or its batched torch twin (``batched.py``)."""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, Sequence, Union

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import Bool, Field, NonNegativeFloat, PositiveInt, finite, is_finite, options, require
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.reach1d.batched import TorchReach1D
from cmdp_rl.envs.reach1d.env import GOAL_TOLERANCE, Reach1D
from cmdp_rl.envs.reach1d.optimum import constrained_optimum
from cmdp_rl.envs.reach1d.population import PopulationReach1D
from cmdp_rl.envs.vector import GymVecEnv, VecEnv

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig

ALLOWED_START = "a number in [0, 1] or a pair [low, high] with 0 <= low <= high <= 1"


@options
class Reach1DConfig(EnvOptions):
    """``env=reach1d``: Reach1D's options, on the gymnasium backend or the batched torch twin."""

    name: str = "reach1d"
    # gym: gymnasium envs in a synchronous vector env; torch: one batched tensor program (batched.py)
    backend: Literal["gym", "torch"] = "gym"
    num_envs: PositiveInt = 8
    obs_noise: NonNegativeFloat = 0.02
    wall_x: Annotated[float, finite(gt=0, lt=1)] = 0.5
    goal: Annotated[float, finite(ge=0, le=1)] = 0.9
    max_steps: PositiveInt = 100
    wall: Literal["block", "pass"] = "block"
    start: Annotated[Union[float, list[float]], Field(description=ALLOWED_START)] = 0.1
    probe: Bool = False
    # torch backend only: the first episodes end at random steps (TorchReach1D says why)
    stagger: Bool = False
    # In Reach1D an episode terminates only at the goal.
    termination_metric: ClassVar[str] = "goal_reached"
    values_snapshots: ClassVar[bool] = True  # deploy.policy=auto (EnvOptions.values_snapshots)

    def env_kwargs(self) -> dict[str, Any]:
        """The :class:`Reach1D` constructor arguments these options ask for."""
        return {k: getattr(self, k) for k in ("obs_noise", "wall_x", "max_steps", "goal", "wall", "start", "probe")}

    def render_env(self) -> Reach1D:
        """One gymnasium Reach1D of these options drawing ``rgb_array`` frames (either backend's video)."""
        return Reach1D(**self.env_kwargs(), render_mode="rgb_array")

    def optimum(self, cost_limit: float) -> float:
        """The end-of-run summary's constrained optimum at ``cost_limit`` (``optimum.py``: true state)."""
        return constrained_optimum(self, cost_limit).value

    def termination_note(self) -> str | None:
        """For the end-of-run summary: why no episode can reach the goal (a blocking wall in the way), if so."""
        lo, hi = (self.start[0], self.start[-1]) if isinstance(self.start, list) else (self.start, self.start)
        goal_right = self.goal > self.wall_x
        starts_opposite = hi < self.wall_x if goal_right else lo > self.wall_x
        # Within GOAL_TOLERANCE of the wall the goal would be reachable from the near side.
        if self.wall == "block" and starts_opposite and abs(self.goal - self.wall_x) >= GOAL_TOLERANCE:
            return (
                "goal out of reach by design: env.wall=block makes the wall impassable, "
                "the best a policy can do is approach it"
            )
        return None

    def valuation_options(self) -> Reach1DConfig:
        """The torch twin: the same CMDP to the last bit (``batched.py``), one tensor program over the
        valuation's thousand-odd episodes instead of as many gymnasium envs stepped in Python."""
        return dataclasses.replace(self, backend="torch", stagger=False)

    def population_env(
        self, env_cfgs: Sequence[Reach1DConfig], num_envs: int, seeds: Sequence[int], device: Any, evaluation: bool
    ) -> VecEnv | None:
        """On the torch backend: one ``PopulationReach1D`` of every agent's envs (evaluation: no stagger)."""
        if self.backend != "torch":
            return None
        env = PopulationReach1D(env_cfgs, num_envs, stagger=self.stagger and not evaluation, device=device)
        env.seed_agents(seeds)
        return env

    def check(self, run: RunConfig) -> None:
        s = self.start if isinstance(self.start, list) else [self.start, self.start]
        ok = len(s) == 2 and all(is_finite(x) for x in s) and 0 <= s[0] <= s[1] <= 1
        require(ok, "env.start", ALLOWED_START, self.start)
        require(
            not self.stagger or self.backend == "torch", "env.stagger", "false unless env.backend=torch", self.stagger
        )


def make_reach1d(cfg: Reach1DConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    """``num_envs`` Reach1D envs on ``cfg.backend``."""
    if cfg.backend == "torch":
        return TorchReach1D(num_envs, **cfg.env_kwargs(), stagger=cfg.stagger, device=device)
    return GymVecEnv(partial(Reach1D, **cfg.env_kwargs()), num_envs, device=device)


register("env", "reach1d", Reach1DConfig, make_reach1d)
