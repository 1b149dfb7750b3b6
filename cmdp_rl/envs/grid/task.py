"""The slippery two-hazard gridworld as a component (``env=grid``): its options, checked before
anything is built, and its vector env of gymnasium ``GridWorld`` envs, each cost's budget its default."""

from __future__ import annotations

from dataclasses import field
from functools import partial
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import ConfigError, Field, PositiveInt, finite, options, require
from cmdp_rl.envs.grid.env import (
    COST_NAMES,
    DEFAULT_BUDGETS,
    DEFAULT_END_PROB,
    DEFAULT_LAYOUT,
    DEFAULT_SLIP,
    GRID_ID,
    GridWorld,
    parse_layout,
)
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.vector import GymVecEnv, VecEnv

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig


@options
class GridEnvConfig(EnvOptions):
    """``env=grid``: layout rows ('S' start, 'G' goal, '#' wall, 'a'/'b' hazards, '.' open), the
    slip probability and the per-step end probability (``env.py`` says why the episodes end at random)."""

    name: str = "grid"
    values_snapshots: ClassVar[bool] = True  # deploy.policy=auto (EnvOptions.values_snapshots)
    backend: Literal["gym"] = "gym"
    num_envs: PositiveInt = 8
    slip: Annotated[float, finite(ge=0, le=1)] = DEFAULT_SLIP
    end_prob: Annotated[float, finite(gt=0, le=1)] = DEFAULT_END_PROB
    layout: Annotated[list[str], Field(description="a list of equal-length rows of S G # a b .")] = field(
        default_factory=lambda: list(DEFAULT_LAYOUT)
    )
    # The costs the env reports, in order: both (K = 2), or one for the algorithms that take K = 1.
    costs: Annotated[
        list[Literal["hazard_a", "hazard_b"]],
        Field(min_length=1, max_length=2, description="a non-empty list of distinct names from hazard_a, hazard_b"),
    ] = field(default_factory=lambda: list(COST_NAMES))

    def check(self, run: RunConfig) -> None:
        allowed = "a non-empty list of distinct names from hazard_a, hazard_b"
        require(len(set(self.costs)) == len(self.costs), "env.costs", allowed, self.costs)
        try:
            parse_layout(self.layout)
        except ValueError as exc:  # the layout's own words: which row or character is wrong
            raise ConfigError(f"env.layout: {exc}") from None

    def env_id(self) -> str:
        return GRID_ID

    def budget(self) -> list[float]:
        budgets = dict(zip(COST_NAMES, DEFAULT_BUDGETS))
        return [budgets[name] for name in self.costs]

    def render_env(self) -> GridWorld:
        """One grid of these options drawing ``rgb_array`` frames (for ``evaluate.py video=true``)."""
        return GridWorld(tuple(self.layout), self.slip, self.end_prob, render_mode="rgb_array")


def make_grid_vec_env(cfg: GridEnvConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    make_one = partial(GridWorld, tuple(cfg.layout), cfg.slip, cfg.end_prob, tuple(cfg.costs))
    return GymVecEnv(make_one, num_envs, device=device, env_id=GRID_ID)


register("env", "grid", GridEnvConfig, make_grid_vec_env)
