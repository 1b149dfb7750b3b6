"""The run-level options (:class:`RunConfig`) and loading, the one place a run's options are put together: Hydra
composes ``configs/`` (every option documented there), :func:`load_config` builds each component's part from the
options class registered under its name (``cmdp_rl.config.registry``), and :func:`validate` runs every part's checks.
Every error names the field and what is allowed, before a single environment step."""

from __future__ import annotations

import importlib.util
from dataclasses import field
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping, Optional, Sequence

from cmdp_rl.config.deploy import DeployConfig
from cmdp_rl.config.deploy import resolve_auto as resolve_deploy
from cmdp_rl.config.reference import ReferenceConfig
from cmdp_rl.config.registry import KINDS, component, declared_base
from cmdp_rl.config.threads import apply_threads
from cmdp_rl.config.validation import (
    AUTO,
    AutoInt,
    Bool,
    ConfigError,
    Field,
    PositiveFloat,
    PositiveInt,
    build,
    options,
    recheck,
    require,
)

TENSORBOARD_MISSING = "logger=tensorboard needs the tensorboard package: pip install 'cmdp_rl[tensorboard]'"
WANDB_MISSING = "logger=wandb needs the wandb package: pip install 'cmdp_rl[wandb]'"
# What a config names when it leaves a component out.
DEFAULTS = {"env": "reach1d", "algo": "ppo_lag", "policy": "mlp"}


def _default(kind: str) -> Any:
    return field(default_factory=lambda: component(kind, DEFAULTS[kind]).options())


@options
class NormalizeConfig:
    """Running normalization of observations and scaling of reward and cost (normalization.py)."""

    obs: Bool = False
    obs_clip: PositiveFloat = 10.0
    reward: Bool = False
    cost: Bool = False


@options
class LoggerConfig:
    """Where metrics go besides metrics.csv (always written): ``csv`` nowhere else, ``tensorboard`` also TensorBoard
    event files in the run's ``tb/`` directory, ``wandb`` also a Weights & Biases run (files in the run's ``wandb/``
    directory; ``project``, ``entity`` and ``mode`` are wandb's, read only with ``logger=wandb``)."""

    name: Literal["csv", "tensorboard", "wandb"] = "csv"
    project: Annotated[str, Field(pattern=r"\S", description="a wandb project name")] = "cmdp_rl"
    entity: Optional[str] = None  # a wandb user or team; None: the account's default
    # offline: files only, no network (upload later with `wandb sync`); online: stream to the server
    mode: Literal["offline", "online"] = "offline"


@options
class RunConfig:
    """A run's options, each documented in configs/config.yaml (the components' in configs/<kind>/<name>.yaml)."""

    env: Any = _default("env")  # the options class registered under env.name
    policy: Any = _default("policy")  # ... under policy.name
    algo: Any = _default("algo")  # ... under algo.name
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    seed: int = 0
    total_steps: PositiveInt = 400_000
    rollout_steps: AutoInt = AUTO  # "auto": from env.num_envs (resolve_auto)
    device: Literal["cpu", "cuda"] = "cpu"
    threads: PositiveInt = 1
    eval_episodes: PositiveInt = 20
    eval_deterministic: Bool = True
    early_terminate: Bool = False  # cmdp_rl/envs/early_termination.py
    deploy: DeployConfig = field(default_factory=DeployConfig)  # the policy deployed at the end: cmdp_rl/deploy/
    checkpoint_every: PositiveInt = 10
    log_interval: PositiveInt = 5
    resume: Annotated[Optional[str], Field(pattern=r"\S", description="null or a run directory")] = None
    overwrite: Bool = False  # cmdp_rl/run/ownership.py
    trust_checkpoint: Bool = False  # runs code from an old checkpoint (docs/checkpoints.md); never saved as true
    normalize: NormalizeConfig = field(default_factory=NormalizeConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)

    def __post_init__(self) -> None:
        resolve_budget(self)  # a config built directly, as a script may, has its task's budget too


@options
class EvalConfig:
    """Options of ``cmdp-evaluate run=<run dir> [key=value ...]``, each documented in its help (cli/evaluate.py)."""

    run: Annotated[str, Field(pattern=r"\S", description="a run directory (run=<dir>)")]
    checkpoint: Optional[str] = None  # another checkpoint file to load into the run's config
    episodes: Annotated[Optional[PositiveInt], Field(description="a positive integer")] = None
    deterministic: Optional[Bool] = None  # mean action; default: the run's eval_deterministic
    seed: Optional[int] = None  # default: the run's evaluation seed (reproduces its eval.json)
    plot: Annotated[Optional[str], Field(pattern=r"(?i)\.png$", description="a path ending in .png")] = None
    plot_episodes: PositiveInt = 3  # episodes drawn in the PNG
    output: Optional[str] = None  # also write the results as JSON to this path
    video: Bool = False  # write mp4s of the policy (cmdp_rl/report/video.py): Reach1D, the velocity tasks
    video_episodes: PositiveInt = 1  # episodes recorded, one mp4 each
    video_dir: Optional[str] = None  # default: <run>/videos
    video_steps: Optional[PositiveInt] = None  # cut each recorded episode after this many steps
    trust_checkpoint: Bool = False  # runs code from an old checkpoint (docs/checkpoints.md)


# The Hydra configs. The checkout keeps them at its root (configs/, beside cmdp_rl/); the wheel ships that
# folder as the package cmdp_rl.configs (setup.py). Whichever this package sits beside is the one read, so a
# checkout run from its root never picks up another install's configs.
_PACKAGE = Path(__file__).resolve().parents[1]  # cmdp_rl/
_PACKAGED_CONFIGS = _PACKAGE / "configs"
_IN_WHEEL = (_PACKAGED_CONFIGS / "config.yaml").is_file()
CONFIG_DIR = _PACKAGED_CONFIGS if _IN_WHEEL else _PACKAGE.parent / "configs"
# Where Hydra's search path finds them (the command's config_path): the package's resources in a wheel.
CONFIG_SOURCE = "pkg://cmdp_rl.configs" if _IN_WHEEL else str(CONFIG_DIR)


def compose_config(overrides: Sequence[str] = (), config_dir: str | Path | None = None) -> RunConfig:
    """The validated config ``cmdp-train <overrides>`` runs: Hydra's compose over the shipped configs
    (:data:`CONFIG_SOURCE`) or ``config_dir`` (groups, presets and tuning files included), then :func:`load_config`."""
    from hydra import compose, initialize_config_dir, initialize_config_module  # the rest needs no Hydra
    from omegaconf import OmegaConf

    if config_dir is None and _IN_WHEEL:
        context = initialize_config_module(config_module="cmdp_rl.configs", version_base="1.3")
    else:
        context = initialize_config_dir(config_dir=str(config_dir or CONFIG_DIR), version_base="1.3")
    with context:
        raw = compose("config", overrides=list(overrides))
    return load_config(OmegaConf.to_container(raw, resolve=True))


def load_config(raw: Mapping[str, Any]) -> RunConfig:
    """Build and validate a :class:`RunConfig` from a plain mapping (a resolved Hydra config) and set torch's thread
    count to its ``threads`` as :func:`cmdp_rl.train` does, so that a script building its own pieces runs as fast."""
    raw = dict(raw)
    raw.pop("hydra", None)
    raw.pop("population", None)  # several agents: cmdp_rl/population/ reads it (spec.agent_configs)
    parts: dict[str, Any] = {}
    for kind in KINDS:
        data = dict(raw.pop(kind, {}) or {})
        parts[kind] = build(component(kind, data.get("name", DEFAULTS[kind])).options, data, kind)
    cfg = build(RunConfig, {**raw, **parts}, "")  # its nested nodes (logger, deploy, ...) built field by field
    validate(cfg)
    apply_threads(cfg)
    return cfg


def flatten_dict(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested config as dotted keys: ``{"algo": {"lr": 1}}`` -> ``{"algo.lr": 1}``."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(flatten_dict(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def resolve_auto(cfg: RunConfig) -> None:
    """Replace the ``"auto"`` batch-shape options by numbers that follow ``env.num_envs``, in place (numbers given
    are kept). A few envs want long rollouts and many passes over a small batch, a thousand batched envs short
    rollouts and one pass over a large one, as in massively parallel PPO (Rudin et al., 2022, "Learning to Walk in
    Minutes Using Massively Parallel Deep RL"): ``rollout_steps`` = 2048 / N within [32, 256], the gym default's 256
    at N <= 8; the algorithm resolves its own (``PPOConfig.resolve_auto``), ``deploy.policy: auto`` becomes
    ``mixture`` or ``last`` (``cmdp_rl/config/deploy.py``)."""
    if cfg.rollout_steps == AUTO:
        auto = cfg.algo.auto_rollout_steps(cfg)  # an off-policy algorithm's few steps
        cfg.rollout_steps = auto if auto is not None else min(256, max(32, 2048 // cfg.env.num_envs))
    resolve_deploy(cfg)
    cfg.algo.resolve_auto(cfg)


def resolve_budget(cfg: RunConfig) -> None:
    """``algo.cost_limit`` left unset (None) becomes the task's budget ``env.budget()`` (d = 25 on the Safety-Gymnasium
    tasks, 1 on Reach1D); a value given wins. In place, so ``config.yaml`` records the budget in force."""
    if cfg.algo.cost_limit is None:
        cfg.algo.cost_limit = cfg.env.budget()


def budget_source(cfg: RunConfig) -> str:
    """Where the budget in force came from, for the line a run starts with."""
    return "the task's" if cfg.algo.cost_limit == cfg.env.budget() else "algo.cost_limit"


def validate(cfg: RunConfig) -> None:
    """Check every field against its declared range (again: a script may have assigned fields), fill the task's budget
    (:func:`resolve_budget`) and the ``"auto"`` options (:func:`resolve_auto`), then run the rules each component
    declares across fields (its ``check(run)``) and the run's own; raise :class:`ConfigError` on the first violation."""
    for kind in KINDS:
        part = getattr(cfg, kind)
        expected = component(kind, getattr(part, "name", None)).options
        require(type(part) is expected, kind, f"a {expected.__name__} for {kind}.name={part.name}", type(part).__name__)
        base = declared_base(kind)
        require(
            base is None or isinstance(part, base),
            kind,
            f"options deriving from {base.__module__}.{base.__qualname__} (the hooks it declares)" if base else "",
            type(part).__name__,
        )
        recheck(part, kind)
    recheck(cfg, "")  # and its nested nodes, each under its own name
    envs = cfg.algo.envs  # an algorithm that trains on some envs only (AlgoConfig.envs)
    require(
        envs is None or cfg.env.name in envs,
        "env",
        f"{' or '.join(envs or ())} with algo={cfg.algo.name}",
        cfg.env.name,
    )
    resolve_budget(cfg)
    resolve_auto(cfg)
    for kind in KINDS:
        if hasattr(getattr(cfg, kind), "check"):
            getattr(cfg, kind).check(cfg)
    if cfg.device == "cuda":
        import torch

        require(torch.cuda.is_available(), "device", "cpu on this machine (torch sees no CUDA device)", cfg.device)
    missing = {"tensorboard": TENSORBOARD_MISSING, "wandb": WANDB_MISSING}.get(cfg.logger.name)
    if missing and importlib.util.find_spec(cfg.logger.name) is None:  # the logger's package, named as it
        raise ConfigError(f"logger.name: {missing}")
    require(
        not (cfg.normalize.cost and cfg.algo.reads_raw_cost),
        "normalize.cost",
        f"false with algo={cfg.algo.name} (it reads costs in their own units)",
        cfg.normalize.cost,
    )
    cfg.deploy.check(cfg)
    cfg.reference.check(cfg)
