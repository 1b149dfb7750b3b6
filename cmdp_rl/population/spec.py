"""What a population is: the ``population`` options, each agent's validated ``RunConfig``, and what
the batched program refuses. Agents are the grid's cartesian product (fields in the order given),
``population.seeds`` seeds per point (innermost); only :data:`PER_AGENT_FIELDS` differ between them."""

from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass, field
from typing import Any, Mapping

import yaml

from cmdp_rl.algos.base import AlgoConfig
from cmdp_rl.algos.ppo import PPO
from cmdp_rl.config.registry import component, names
from cmdp_rl.config.run_config import CONFIG_DIR, RunConfig, flatten_dict, load_config
from cmdp_rl.config.validation import ConfigError, PositiveInt, build, options, require
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.policies.distributions import CategoricalHead, GaussianHead

# The fields a population may vary per agent, and the seed: configs/population/none.yaml's grid.
PER_AGENT_FIELDS = tuple(flatten_dict(yaml.safe_load((CONFIG_DIR / "population" / "none.yaml").read_text())["grid"]))


def batched(algo: str, base: str | None = None, whole: bool = False) -> bool:
    """Whether ``algo``'s agents train as one batched program: envs and acting at once, and the update
    (``whole``, :func:`stacked`) where it is ``PPO.update`` (variants live in ``ppo.ppo_update``'s
    per-agent hooks), else each agent's own ``policy_update`` and one ``fit_critics`` (trust region).
    Not an algorithm with envs of its own kind, nor one that acts at random first (off-policy warm-up);
    a composition (Sauté) as its ``base`` (where the config names it, else its default)."""
    comp = component("algo", algo)
    if comp.options.envs is not None or comp.options.uniform_action_steps is not AlgoConfig.uniform_action_steps:
        return False
    if not isinstance(comp.build, type):
        base = base or getattr(comp.options, "base", None)
        return isinstance(base, str) and base != algo and batched(base, whole=whole)
    if issubclass(comp.build, PPO) and comp.build.update is PPO.update:
        return True
    return not whole and all(callable(getattr(comp.build, h, None)) for h in ("policy_update", "fit_critics"))


def stacked(algo: str, base: str | None = None) -> bool:
    return batched(algo, base, whole=True)


def batched_algos() -> list[str]:
    """Every registered algorithm whose population is one batched program."""
    return [n for n in names("algo") if batched(n)]


@options
class PopulationConfig:
    """``population.seeds``: seeds per grid point; ``population.grid``: field -> list of values (null: not varied)."""

    seeds: PositiveInt = 1
    grid: dict = field(default_factory=dict)

    def fields(self) -> dict[str, list]:
        """The varied fields and their values, in configs/population/none.yaml's order."""
        return {k: v for k, v in flatten_dict(self.grid or {}).items() if v is not None}


def population_spec(raw: Mapping[str, Any] | None) -> PopulationConfig:
    spec = build(PopulationConfig, dict(raw or {}), "population")
    for name, values in spec.fields().items():
        where = f"population.grid.{name}"
        require(name in PER_AGENT_FIELDS, where, f"one of the per-agent fields {list(PER_AGENT_FIELDS)}", values)
        require(isinstance(values, list) and len(values) > 0, where, "a non-empty list", values)
    return spec


def population_active(raw: Mapping[str, Any] | None) -> bool:
    """Whether ``raw`` (the ``population`` node of a composed config) asks for more than one agent."""
    spec = population_spec(raw)
    return spec.seeds > 1 or bool(spec.fields())


def agent_overrides(spec: PopulationConfig, base_seed: int) -> list[dict[str, Any]]:
    """Each agent's values of the varied fields and its seed (innermost), in population order."""
    grid = spec.fields()
    if "seed" in grid and spec.seeds > 1:
        raise ConfigError(f"population.seeds must be 1 when population.grid.seed lists the seeds, got {spec.seeds}")
    seeds = grid.pop("seed", [base_seed + j for j in range(spec.seeds)])
    return [{**dict(zip(grid, combo)), "seed": s} for combo in itertools.product(*grid.values()) for s in seeds]


def label(overrides: Mapping[str, Any]) -> str:
    """An agent's directory label: its values, e.g. ``algo.penalty=0.5,seed=1``."""

    def fmt(v: Any) -> str:
        return "[" + ",".join(fmt(x) for x in v) + "]" if isinstance(v, list) else str(v)

    return ",".join(f"{k}={fmt(v)}" for k, v in overrides.items())


def agent_configs(raw: Mapping[str, Any]) -> tuple[list[dict[str, Any]], list[RunConfig]]:
    """Each agent's overrides and validated config from a composed config holding ``population``; a
    value the field's rules refuse stops here, in one line naming the grid field."""
    raw = {k: v for k, v in raw.items() if k != "hydra"}
    spec = population_spec(raw.pop("population", None))
    overrides = agent_overrides(spec, int(raw.get("seed", 0)))
    cfgs = []
    for i, ov in enumerate(overrides):
        data = copy.deepcopy(raw)
        for name, value in ov.items():
            *parents, last = name.split(".")
            node = data
            for p in parents:
                node = node.setdefault(p, {})
            node[last] = copy.deepcopy(value)
        try:
            cfgs.append(load_config(data))
        except ConfigError as exc:
            varied = [k for k in ov if k != "seed" or "seed" in spec.fields()]
            where = f"population.grid.{varied[0]}" if len(varied) == 1 else "population"
            raise ConfigError(f"{where}: agent {i} ({label(ov)}): {exc}") from exc
    return overrides, cfgs


@dataclass
class Population:
    """What ``population.training.train_population`` trains as P members: the composed config (``population.yaml``), each agent's
    ``overrides`` and config, a resume's checkpoint ``state`` (None where agents keep their own)."""

    raw: dict[str, Any]
    overrides: list[dict[str, Any]]
    cfgs: list[RunConfig]
    resume: bool = False
    state: dict[str, Any] | None = None


def population(raw: Mapping[str, Any], resume: bool = False, state: dict | None = None) -> Population:
    """The population ``raw`` (a composed config with a ``population`` node) describes. Trusting a
    checkpoint or resuming is one command's word, not the population's."""
    raw = {**copy.deepcopy({k: v for k, v in raw.items() if k != "hydra"}), "resume": None, "trust_checkpoint": False}
    return Population(raw, *agent_configs(raw), resume=resume, state=state)


def unbatched(cfg: RunConfig) -> str | None:
    """Why the batched program does not cover agents of ``cfg`` (they then train one after another),
    or None; the action space is checked on the built agent (:func:`unbatched_head`)."""
    if not batched(cfg.algo.name, getattr(cfg.algo, "base", None)):
        return f"algo={cfg.algo.name} is not batched (the batched algorithms: {', '.join(batched_algos())})"
    if cfg.policy.name != "mlp" or cfg.policy.include_prev_action or cfg.policy.include_prev_cost:
        with_prev = " with include_prev_*" if cfg.policy.name == "mlp" else ""
        return f"policy={cfg.policy.name}{with_prev} is not batched (mlp on the observation is)"
    # Envs in this process whose state a checkpoint holds: a torch backend's, or one backend's with
    # a population form of its own (safe_nav's P N worlds).
    backend = getattr(cfg.env, "backend", None)
    own_form = type(cfg.env).population_env is not EnvOptions.population_env
    if not (backend == "torch" or (backend is None and own_form)):
        return f"env={cfg.env.name} (backend {backend}) is not batched (env.backend=torch, or env=safe_nav, is)"
    if getattr(cfg.env, "probe", False):
        return "env.probe=true is not batched"
    if cfg.normalize.obs or cfg.normalize.reward or cfg.normalize.cost:
        return "normalize is not batched"
    if cfg.logger.name not in ("csv", "tensorboard"):  # W&B: one process would hold P runs
        return f"logger={cfg.logger.name} is not batched (csv and tensorboard are)"
    if cfg.reference.run is not None or cfg.reference.episode_return is not None:
        return "reference.* is not batched"
    if isinstance(getattr(cfg.algo, "penalty", 0.0), list):
        return "a list algo.penalty is not batched"
    return None


def unbatched_head(head: Any) -> str | None:
    """Why the batched program does not cover an agent's action head (a Box's or a Discrete's), or None."""
    if isinstance(head, (GaussianHead, CategoricalHead)) and not getattr(head, "sizes", None):
        return None
    return f"the action head {type(head).__name__} is not batched (a Box or a Discrete action space is)"
