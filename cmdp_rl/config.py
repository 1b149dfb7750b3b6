"""Typed run configuration, checked in one place before anything is built.

The YAML files under ``configs/`` document every option; Hydra composes them and
:func:`load_config` turns the result into these dataclasses. Each range check names the field and
what is allowed, so a bad value fails before a single environment step.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union, get_args, get_origin, get_type_hints


class ConfigError(ValueError):
    """A config value is missing, of the wrong type, or out of range."""


LOGGERS = ("csv", "tensorboard")
TENSORBOARD_MISSING = "logger=tensorboard needs the tensorboard package: pip install 'cmdp_rl[tensorboard]'"
ENV_NAMES = ("reach1d", "velocity", "gym")
ENV_BACKENDS = ("gym", "torch")  # gymnasium vector env | tensor-native batched env (reach1d only)
WALL_MODES = ("block", "pass")
POLICY_NAMES = ("mlp", "lstm", "gru", "transformer")
ACTIVATIONS = ("tanh", "relu", "elu")
DEVICES = ("cpu", "cuda")
AUTO = "auto"  # rollout_steps, algo.update_epochs, algo.num_minibatches: follow env.num_envs


@dataclass
class EnvConfig:
    name: str = "reach1d"
    backend: str = "gym"
    num_envs: int = 8
    obs_noise: float = 0.02
    wall_x: float = 0.5
    goal: float = 0.9
    max_steps: int = 100
    wall: str = "block"
    start: Union[float, list] = 0.1
    probe: bool = False
    # torch backend only: the first episode of each env starts at a random step count, so that
    # episodes end at different iterations (the envs would otherwise all time out together).
    stagger: bool = False


# Safety-Gymnasium's velocity tasks (v1 thresholds), on gymnasium's MuJoCo v5 envs: envs/velocity.py.
VELOCITY_TASKS = ("Ant", "HalfCheetah", "Hopper", "Humanoid", "Swimmer", "Walker2d")
STEP_APIS = ("five", "six")


@dataclass
class VelocityEnvConfig:
    """A MuJoCo locomotion task with cost 1 on every step faster than a threshold (envs/velocity.py)."""

    name: str = "velocity"
    backend: str = "gym"
    num_envs: int = 8
    task: str = "HalfCheetah"
    # None: the task's Safety-Gymnasium v1 threshold (envs/velocity.py); a number overrides it.
    velocity_threshold: Optional[float] = None
    max_steps: int = 1000


@dataclass
class GymEnvConfig:
    """Any registered gymnasium env that reports cost: in ``info["cost"]`` (five-value step) or as
    the third value of a Safety-Gymnasium six-value step (envs/gym_cost.py)."""

    name: str = "gym"
    backend: str = "gym"
    num_envs: int = 8
    id: str = ""
    step_api: str = "five"
    max_steps: int = 0  # 0: the time limit the env was registered with
    kwargs: dict = field(default_factory=dict)


ENV_CONFIGS: dict[str, type] = {"reach1d": EnvConfig, "velocity": VelocityEnvConfig, "gym": GymEnvConfig}


@dataclass
class NormalizeConfig:
    """Running normalization of observations and scaling of reward and cost (normalization.py)."""

    obs: bool = False
    obs_clip: float = 10.0
    reward: bool = False
    cost: bool = False


@dataclass
class ReferenceConfig:
    """The unconstrained-PPO reference of Safety Gym's normalized metrics (safety_metrics.py):
    a finished run's directory, or its numbers."""

    run: Optional[str] = None
    episode_return: Optional[float] = None
    episode_cost: Optional[float] = None
    cost_rate: Optional[float] = None


# Cost scaling changes what these algorithms' numbers mean: penalty's fixed lambda prices raw
# cost, and CPO's constraint step compares the cost surrogate with J_c - d in raw units.
NO_COST_SCALING = ("penalty", "cpo")


@dataclass
class PolicyConfig:
    """The memoryless MLP policy (policies/mlp.py). ``include_prev_*``: every policy may also read
    the previous step's action and cost (zero on an episode's first step)."""

    name: str = "mlp"
    hidden_sizes: list = field(default_factory=lambda: [64, 64])
    activation: str = "tanh"
    init_log_std: float = -0.5
    include_prev_action: bool = False
    include_prev_cost: bool = False


@dataclass
class RecurrentPolicyConfig:
    """LSTM or GRU memory in the actor and in both critics (policies/recurrent.py)."""

    name: str = "lstm"
    hidden_size: int = 64       # recurrent units
    num_layers: int = 1         # stacked recurrent layers
    head_sizes: list = field(default_factory=lambda: [64])  # MLP after the memory ([]: linear)
    activation: str = "tanh"
    init_log_std: float = -0.5
    include_prev_action: bool = True
    include_prev_cost: bool = True
    # Training segments: steps per segment, a divisor of rollout_steps; 0 or >= rollout_steps:
    # whole rollout rows.
    segment_length: int = 32


@dataclass
class TransformerPolicyConfig:
    """Causal self-attention over the last ``window`` steps (policies/transformer.py)."""

    name: str = "transformer"
    window: int = 16            # K: steps attended to, this one included
    layers: int = 1
    heads: int = 2
    width: int = 32             # model width d (divisible by heads)
    feedforward: int = 64       # hidden width of each layer's feed-forward block
    positions: str = "learned"  # learned | sinusoidal
    head_sizes: list = field(default_factory=lambda: [64])
    activation: str = "tanh"
    init_log_std: float = -0.5
    include_prev_action: bool = True
    include_prev_cost: bool = True


POLICY_CONFIGS: dict[str, type] = {
    "mlp": PolicyConfig, "lstm": RecurrentPolicyConfig, "gru": RecurrentPolicyConfig,
    "transformer": TransformerPolicyConfig,
}
POSITIONS = ("learned", "sinusoidal")


@dataclass
class AlgoConfig:
    """Options every algorithm shares: discounts, GAE, the critics, the budget."""

    name: str = "ppo"
    critic_lr: float = 1e-3
    gamma: float = 0.99
    gae_lambda: float = 0.95
    cost_gamma: float = 0.99
    max_grad_norm: float = 0.5
    normalize_advantage: bool = True
    # The budget d on expected undiscounted episode cost. Only constrained algorithms act on it;
    # every run reports against it.
    cost_limit: float = 1.0


@dataclass
class PPOConfig(AlgoConfig):
    """Clipped PPO (Schulman et al., 2017). Shared by every PPO-family algorithm."""

    name: str = "ppo"
    lr: float = 3e-4
    clip_epsilon: float = 0.2
    # "auto": about 80 minibatch steps per iteration (resolve_auto), 10 x 8 for a batch of 2048.
    update_epochs: Union[int, str] = AUTO
    num_minibatches: Union[int, str] = AUTO
    entropy_coef: float = 0.0


@dataclass
class PenaltyConfig(PPOConfig):
    """PPO on r - penalty * c with a fixed exchange rate."""

    name: str = "penalty"
    penalty: float = 1.0


@dataclass
class PPOLagConfig(PPOConfig):
    """PPO-Lagrangian (Ray, Achiam, Amodei 2019): lambda adapted by projected dual ascent."""

    name: str = "ppo_lag"
    lambda_init: float = 0.0
    lambda_lr: float = 0.05


@dataclass
class PIDLagConfig(PPOConfig):
    """PPO with lambda set by a PID controller (Stooke, Achiam, Abbeel 2020)."""

    name: str = "pid_lag"
    lambda_init: float = 0.0
    kp: float = 2.0
    ki: float = 0.1
    kd: float = 0.0
    p_ema_alpha: float = 0.0
    d_ema_alpha: float = 0.0
    d_delay: int = 1
    lambda_max: float = math.inf


@dataclass
class CPOConfig(AlgoConfig):
    """Constrained Policy Optimization (Achiam, Held, Tamar, Abbeel 2017)."""

    name: str = "cpo"
    target_kl: float = 0.01
    cg_iters: int = 10
    cg_damping: float = 0.1
    line_search_steps: int = 10
    backtrack_coef: float = 0.8
    critic_epochs: int = 10
    critic_minibatches: int = 8


ALGO_CONFIGS: dict[str, type] = {
    "ppo": PPOConfig, "penalty": PenaltyConfig, "ppo_lag": PPOLagConfig, "pid_lag": PIDLagConfig,
    "cpo": CPOConfig,
}


@dataclass
class LoggerConfig:
    """Where metrics go besides metrics.csv (always written): ``csv`` nowhere else,
    ``tensorboard`` also TensorBoard event files in the run's ``tb/`` directory."""

    name: str = "csv"


@dataclass
class RunConfig:
    env: Union[EnvConfig, VelocityEnvConfig, GymEnvConfig] = field(default_factory=EnvConfig)
    policy: Union[PolicyConfig, RecurrentPolicyConfig, TransformerPolicyConfig] = field(default_factory=PolicyConfig)
    algo: AlgoConfig = field(default_factory=PPOLagConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    seed: int = 0
    total_steps: int = 400_000
    rollout_steps: Union[int, str] = AUTO  # "auto": from env.num_envs (resolve_auto)
    device: str = "cpu"
    threads: int = 1
    eval_episodes: int = 20
    eval_deterministic: bool = True
    checkpoint_every: int = 10
    log_interval: int = 5
    # A run directory to continue from its last checkpoint (see cmdp_rl/resume.py); None: a new run.
    resume: Optional[str] = None
    normalize: NormalizeConfig = field(default_factory=NormalizeConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)


@dataclass
class EvalConfig:
    """Options of ``evaluate.py`` (``python evaluate.py run=<run dir> [key=value ...]``)."""

    run: Optional[str] = None  # the run directory (required)
    checkpoint: Optional[str] = None  # another checkpoint file to load into the run's config
    episodes: Optional[int] = None  # default: the run's eval_episodes
    deterministic: Optional[bool] = None  # mean action; default: the run's eval_deterministic
    seed: Optional[int] = None  # default: the run's evaluation seed (reproduces its eval.json)
    plot: Optional[str] = None  # Reach1D: write a PNG of replayed episodes to this path
    plot_episodes: int = 3  # episodes drawn in the PNG
    output: Optional[str] = None  # also write the results as JSON to this path


def _check_type(value: Any, hint: Any, name: str) -> Any:
    """Coerce ``value`` to ``hint`` where that is lossless; otherwise raise naming the field."""
    origin = get_origin(hint)
    if origin is Union:
        for option in get_args(hint):
            try:
                return _check_type(value, option, name)
            except ConfigError:
                continue
        raise ConfigError(f"{name}: expected one of {get_args(hint)}, got {value!r}")
    if hint is type(None):
        if value is None:
            return None
        raise ConfigError(f"{name}: expected null, got {value!r}")
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{name}: expected true or false, got {value!r}")
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ConfigError(f"{name}: expected an integer, got {value!r}")
    if hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise ConfigError(f"{name}: expected a number, got {value!r}")
    if hint is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"{name}: expected a string, got {value!r}")
    if hint is list or origin is list:
        if isinstance(value, (list, tuple)):
            return list(value)
        raise ConfigError(f"{name}: expected a list, got {value!r}")
    return value


def _build(cls: type, data: Mapping[str, Any], prefix: str) -> Any:
    hints = get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"{prefix}: unknown option(s) {unknown}; allowed: {sorted(names)}")
    kwargs = {k: _check_type(v, hints[k], f"{prefix}.{k}") for k, v in data.items()}
    return cls(**kwargs)


# The repository's Hydra configs (train.py's config_path), beside the package in a source checkout.
CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


def compose_config(overrides: Sequence[str] = (), config_dir: str | Path = CONFIG_DIR) -> RunConfig:
    """The validated config ``python train.py <overrides>`` runs: Hydra's compose over
    ``config_dir`` (groups, presets and tuning files included), then :func:`load_config`."""
    from hydra import compose, initialize_config_dir  # here: the rest of this module needs no Hydra
    from omegaconf import OmegaConf

    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3"):
        raw = compose("config", overrides=list(overrides))
    return load_config(OmegaConf.to_container(raw, resolve=True))


def load_config(raw: Mapping[str, Any]) -> RunConfig:
    """Build and validate a :class:`RunConfig` from a plain mapping (e.g. a resolved Hydra config)."""
    raw = dict(raw)
    raw.pop("hydra", None)
    algo = dict(raw.pop("algo", {}) or {})
    algo_name = algo.get("name", "ppo_lag")
    if algo_name not in ALGO_CONFIGS:
        raise ConfigError(f"algo.name: unknown algorithm {algo_name!r}; allowed: {sorted(ALGO_CONFIGS)}")
    cfg = _build(
        RunConfig,
        {k: v for k, v in raw.items() if k not in ("env", "policy", "logger", "normalize", "reference")},
        "config",
    )
    cfg.logger = _build(LoggerConfig, dict(raw.get("logger", {}) or {}), "logger")
    env = dict(raw.get("env", {}) or {})
    env_name = env.get("name", "reach1d")
    if env_name not in ENV_CONFIGS:
        raise ConfigError(f"env.name: unknown env {env_name!r}; allowed: {sorted(ENV_CONFIGS)}")
    cfg.env = _build(ENV_CONFIGS[env_name], env, "env")
    cfg.normalize = _build(NormalizeConfig, dict(raw.get("normalize", {}) or {}), "normalize")
    cfg.reference = _build(ReferenceConfig, dict(raw.get("reference", {}) or {}), "reference")
    policy = dict(raw.get("policy", {}) or {})
    policy_name = policy.get("name", "mlp")
    if policy_name not in POLICY_CONFIGS:
        raise ConfigError(f"policy.name: unknown policy {policy_name!r}; allowed: {sorted(POLICY_CONFIGS)}")
    cfg.policy = _build(POLICY_CONFIGS[policy_name], policy, "policy")
    cfg.algo = _build(ALGO_CONFIGS[algo_name], algo, "algo")
    validate(cfg)
    return cfg


def load_eval_config(raw: Mapping[str, Any]) -> EvalConfig:
    """Build and check ``evaluate.py``'s options."""
    cfg = _build(EvalConfig, dict(raw), "evaluate")
    _require(bool(cfg.run), "run", "a run directory (run=<dir>)", cfg.run)
    _require(cfg.episodes is None or cfg.episodes >= 1, "episodes", "a positive integer", cfg.episodes)
    _require(cfg.plot_episodes >= 1, "plot_episodes", "a positive integer", cfg.plot_episodes)
    _require(cfg.plot is None or cfg.plot.lower().endswith(".png"), "plot", "a path ending in .png", cfg.plot)
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


def _require(ok: bool, name: str, allowed: str, value: Any) -> None:
    if not ok:
        raise ConfigError(f"{name} must be {allowed}, got {value!r}")


def _finite(x: float) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def resolve_auto(cfg: RunConfig) -> None:
    """Replace the ``"auto"`` batch-shape options by numbers that follow ``env.num_envs``.

    A few envs (the gymnasium default of 8) want long rollouts and many passes over a small batch;
    a thousand batched envs want short rollouts and one pass over a large one, as in massively
    parallel PPO (Rudin et al., 2022, "Learning to Walk in Minutes Using Massively Parallel Deep RL").
    The rules keep what the gym default does at N <= 8 exactly and scale from there:

    - ``rollout_steps`` = 2048 / N, within [32, 256]: 256 for N <= 8, 32 for N >= 64;
    - ``algo.num_minibatches``: 8 while the batch is at most 2048 steps, else one per 512 steps,
      at most 64 (minibatches of 512 at N = 1024, larger beyond);
    - ``algo.update_epochs`` = 80 / num_minibatches rounded, at least 1: about 80 minibatch steps per
      iteration, the gym default's 10 x 8. (PPO-Lagrangian moves lambda once per iteration; with
      16 or 32 steps per iteration at N = 1024, lambda overshot and the policy collapsed.)

    Numbers given in the config are kept. Works in place; called by :func:`validate`.
    """
    n = cfg.env.num_envs
    if not (isinstance(n, int) and n >= 1):
        return  # validate names env.num_envs
    if cfg.rollout_steps == AUTO:
        cfg.rollout_steps = min(256, max(32, 2048 // n))
    a = cfg.algo
    if isinstance(a, PPOConfig) and isinstance(cfg.rollout_steps, int):
        batch = cfg.rollout_steps * n
        if a.num_minibatches == AUTO:
            a.num_minibatches = 8 if batch <= 2048 else min(64, batch // 512)
        if a.update_epochs == AUTO and isinstance(a.num_minibatches, int):
            # (validate names a num_minibatches below 1; max() only keeps this from dividing by it)
            a.update_epochs = max(1, round(80 / max(1, a.num_minibatches)))
    for name, value in (("rollout_steps", cfg.rollout_steps),  # words other than "auto"
                        ("algo.num_minibatches", getattr(a, "num_minibatches", 1)),
                        ("algo.update_epochs", getattr(a, "update_epochs", 1))):
        _require(isinstance(value, int), name, f"a positive integer or {AUTO!r}", value)


def validate(cfg: RunConfig) -> None:
    """Fill the ``"auto"`` options (:func:`resolve_auto`), then raise :class:`ConfigError` on the
    first out-of-range field."""
    resolve_auto(cfg)
    e, a = cfg.env, cfg.algo
    _require(e.name in ENV_NAMES, "env.name", f"one of {ENV_NAMES}", e.name)
    _require(e.backend in ENV_BACKENDS, "env.backend", f"one of {ENV_BACKENDS}", e.backend)
    _require(e.num_envs >= 1, "env.num_envs", "a positive integer", e.num_envs)
    if isinstance(e, EnvConfig):
        _require(_finite(e.obs_noise) and e.obs_noise >= 0, "env.obs_noise", "a number >= 0", e.obs_noise)
        _require(0.0 < e.wall_x < 1.0, "env.wall_x", "in (0, 1)", e.wall_x)
        _require(0.0 <= e.goal <= 1.0, "env.goal", "in [0, 1]", e.goal)
        _require(e.max_steps >= 1, "env.max_steps", "a positive integer", e.max_steps)
        _require(e.wall in WALL_MODES, "env.wall", f"one of {WALL_MODES}", e.wall)
        if isinstance(e.start, list):
            ok = len(e.start) == 2 and all(_finite(s) for s in e.start) and 0 <= e.start[0] <= e.start[1] <= 1
            _require(ok, "env.start", "a number in [0, 1] or a pair [low, high] with 0 <= low <= high <= 1", e.start)
        else:
            _require(0.0 <= e.start <= 1.0, "env.start", "in [0, 1]", e.start)
        _require(not e.stagger or e.backend == "torch", "env.stagger", "false unless env.backend=torch", e.stagger)
    else:
        _require(e.backend == "gym", "env.backend", f"gym for env={e.name}", e.backend)
    if isinstance(e, VelocityEnvConfig):
        _require(e.task in VELOCITY_TASKS, "env.task", f"one of {VELOCITY_TASKS}", e.task)
        _require(e.velocity_threshold is None or (_finite(e.velocity_threshold) and e.velocity_threshold >= 0),
                 "env.velocity_threshold", "null (the task's own) or a number >= 0", e.velocity_threshold)
        _require(e.max_steps >= 1, "env.max_steps", "a positive integer", e.max_steps)
    if isinstance(e, GymEnvConfig):
        _require(e.id.strip() != "", "env.id", "a registered gymnasium id, e.g. env.id=MyCostEnv-v0", e.id)
        _require(e.step_api in STEP_APIS, "env.step_api", f"one of {STEP_APIS}", e.step_api)
        _require(e.max_steps >= 0, "env.max_steps", "an integer >= 0 (0: the registered limit)", e.max_steps)
        _require(isinstance(e.kwargs, dict), "env.kwargs", "a mapping of constructor arguments", e.kwargs)

    _validate_policy(cfg)

    _require(_finite(a.critic_lr) and a.critic_lr > 0, "algo.critic_lr", "a positive number", a.critic_lr)
    for g in ("gamma", "cost_gamma"):
        v = getattr(a, g)
        _require(0.0 <= v < 1.0, f"algo.{g}", "in [0, 1)", v)
    _require(0.0 <= a.gae_lambda <= 1.0, "algo.gae_lambda", "in [0, 1]", a.gae_lambda)
    _require(a.max_grad_norm > 0, "algo.max_grad_norm", "a positive number", a.max_grad_norm)
    _require(_finite(a.cost_limit) and a.cost_limit >= 0, "algo.cost_limit", "a number >= 0 (the budget d)", a.cost_limit)
    if isinstance(a, PPOConfig):
        _require(_finite(a.lr) and a.lr > 0, "algo.lr", "a positive number", a.lr)
        _require(0.0 < a.clip_epsilon < 1.0, "algo.clip_epsilon", "in (0, 1)", a.clip_epsilon)
        _require(a.update_epochs >= 1, "algo.update_epochs", "a positive integer", a.update_epochs)
        _require(a.num_minibatches >= 1, "algo.num_minibatches", "a positive integer", a.num_minibatches)
        _require(a.entropy_coef >= 0, "algo.entropy_coef", "a number >= 0", a.entropy_coef)
    if isinstance(a, PenaltyConfig):
        _require(_finite(a.penalty) and a.penalty >= 0, "algo.penalty", "a number >= 0", a.penalty)
    if isinstance(a, PPOLagConfig):
        _require(a.lambda_init >= 0, "algo.lambda_init", "a number >= 0", a.lambda_init)
        _require(a.lambda_lr > 0, "algo.lambda_lr", "a positive number", a.lambda_lr)
    if isinstance(a, PIDLagConfig):
        for gain in ("kp", "ki", "kd"):
            v = getattr(a, gain)
            _require(_finite(v) and v >= 0, f"algo.{gain}", "a number >= 0", v)
        _require(a.kp + a.ki + a.kd > 0, "algo.kp + algo.ki + algo.kd", "> 0 (some gain must act)", a.kp + a.ki + a.kd)
        for ema in ("p_ema_alpha", "d_ema_alpha"):
            v = getattr(a, ema)
            _require(0.0 <= v < 1.0, f"algo.{ema}", "in [0, 1)", v)
        _require(a.d_delay >= 1, "algo.d_delay", "a positive integer", a.d_delay)
        _require(a.lambda_max > 0 and not math.isnan(a.lambda_max), "algo.lambda_max", "a positive number or .inf", a.lambda_max)
        _require(_finite(a.lambda_init) and 0 <= a.lambda_init <= a.lambda_max, "algo.lambda_init",
                 "a number in [0, algo.lambda_max]", a.lambda_init)
    if isinstance(a, CPOConfig):
        _require(_finite(a.target_kl) and a.target_kl > 0, "algo.target_kl", "a positive number (the KL radius delta)", a.target_kl)
        _require(a.cg_iters >= 1, "algo.cg_iters", "a positive integer", a.cg_iters)
        _require(_finite(a.cg_damping) and a.cg_damping >= 0, "algo.cg_damping", "a number >= 0", a.cg_damping)
        _require(a.line_search_steps >= 1, "algo.line_search_steps", "a positive integer", a.line_search_steps)
        _require(0.0 < a.backtrack_coef < 1.0, "algo.backtrack_coef", "in (0, 1)", a.backtrack_coef)
        _require(a.critic_epochs >= 1, "algo.critic_epochs", "a positive integer", a.critic_epochs)
        _require(a.critic_minibatches >= 1, "algo.critic_minibatches", "a positive integer", a.critic_minibatches)

    _require(cfg.total_steps >= 1, "total_steps", "a positive integer", cfg.total_steps)
    _require(cfg.rollout_steps >= 1, "rollout_steps", "a positive integer", cfg.rollout_steps)
    batch = cfg.rollout_steps * e.num_envs
    if isinstance(a, PPOConfig):
        _require(
            batch >= a.num_minibatches, "algo.num_minibatches",
            f"at most rollout_steps * env.num_envs = {batch}", a.num_minibatches,
        )
    if isinstance(a, CPOConfig):
        _require(
            batch >= a.critic_minibatches, "algo.critic_minibatches",
            f"at most rollout_steps * env.num_envs = {batch}", a.critic_minibatches,
        )
    _require(cfg.device in DEVICES, "device", f"one of {DEVICES}", cfg.device)
    if cfg.device == "cuda":
        import torch

        _require(torch.cuda.is_available(), "device", "cpu on this machine (torch sees no CUDA device)", cfg.device)
    _require(cfg.threads >= 1, "threads", "a positive integer", cfg.threads)
    _require(cfg.eval_episodes >= 1, "eval_episodes", "a positive integer", cfg.eval_episodes)
    _require(cfg.checkpoint_every >= 1, "checkpoint_every", "a positive integer", cfg.checkpoint_every)
    _require(cfg.log_interval >= 1, "log_interval", "a positive integer", cfg.log_interval)
    _require(cfg.resume is None or cfg.resume.strip() != "", "resume", "null or a run directory", cfg.resume)
    _require(cfg.logger.name in LOGGERS, "logger.name", f"one of {LOGGERS}", cfg.logger.name)
    if cfg.logger.name == "tensorboard" and importlib.util.find_spec("tensorboard") is None:
        raise ConfigError(f"logger.name: {TENSORBOARD_MISSING}")
    _validate_normalize_and_reference(cfg)


def _validate_policy(cfg: RunConfig) -> None:
    p = cfg.policy
    _require(p.name in POLICY_NAMES, "policy.name", f"one of {POLICY_NAMES}", p.name)
    _require(isinstance(p, POLICY_CONFIGS[p.name]), "policy", f"a {POLICY_CONFIGS[p.name].__name__} for policy.name={p.name}",
             type(p).__name__)
    _require(p.activation in ACTIVATIONS, "policy.activation", f"one of {ACTIVATIONS}", p.activation)
    _require(_finite(p.init_log_std), "policy.init_log_std", "a finite number", p.init_log_std)
    if isinstance(p, PolicyConfig):
        _require(
            len(p.hidden_sizes) >= 1 and all(isinstance(h, int) and h > 0 for h in p.hidden_sizes),
            "policy.hidden_sizes", "a non-empty list of positive integers", p.hidden_sizes,
        )
        return
    _require(all(isinstance(h, int) and h > 0 for h in p.head_sizes),
             "policy.head_sizes", "a list of positive integers (may be empty)", p.head_sizes)
    if isinstance(p, RecurrentPolicyConfig):
        _require(p.hidden_size >= 1, "policy.hidden_size", "a positive integer", p.hidden_size)
        _require(p.num_layers >= 1, "policy.num_layers", "a positive integer", p.num_layers)
        L, T = p.segment_length, cfg.rollout_steps
        _require(L >= 0 and (L == 0 or L >= T or T % L == 0), "policy.segment_length",
                 f"0 or >= rollout_steps (whole rollouts), or a divisor of rollout_steps={T}", L)
        segments = cfg.env.num_envs * (T // L if 0 < L < T else 1)
        for name in ("num_minibatches", "critic_minibatches"):  # PPO family, CPO's critic fit
            if hasattr(cfg.algo, name):
                _require(getattr(cfg.algo, name) <= segments, f"algo.{name}",
                         f"at most the number of training segments, env.num_envs * rollout_steps / "
                         f"policy.segment_length = {segments} (recurrent policies train on whole segments)",
                         getattr(cfg.algo, name))
    if isinstance(p, TransformerPolicyConfig):
        _require(p.window >= 1, "policy.window", "a positive integer (steps attended to)", p.window)
        _require(p.layers >= 1, "policy.layers", "a positive integer", p.layers)
        _require(p.heads >= 1, "policy.heads", "a positive integer", p.heads)
        _require(p.width >= 1 and p.width % p.heads == 0, "policy.width",
                 f"a positive multiple of policy.heads={p.heads}", p.width)
        _require(p.feedforward >= 1, "policy.feedforward", "a positive integer", p.feedforward)
        _require(p.positions in POSITIONS, "policy.positions", f"one of {POSITIONS}", p.positions)


def _validate_normalize_and_reference(cfg: RunConfig) -> None:
    n, r = cfg.normalize, cfg.reference
    _require(_finite(n.obs_clip) and n.obs_clip > 0, "normalize.obs_clip", "a positive number", n.obs_clip)
    _require(not (n.cost and cfg.algo.name in NO_COST_SCALING), "normalize.cost",
             f"false with algo={cfg.algo.name} (it reads costs in their own units)", n.cost)
    numbers = {"episode_return": r.episode_return, "episode_cost": r.episode_cost, "cost_rate": r.cost_rate}
    if r.run is not None:
        _require(all(v is None for v in numbers.values()), "reference",
                 "either reference.run or the reference numbers, not both", {"run": r.run, **numbers})
        _require((Path(r.run) / "eval.json").is_file() and (Path(r.run) / "config.yaml").is_file(),
                 "reference.run", "a finished run's directory (holding eval.json and config.yaml)", r.run)
        from cmdp_rl.safety_metrics import reference_run_problem  # reads the run's files

        problem = reference_run_problem(r.run, cfg)
        _require(problem is None, "reference.run", f"a usable reference run, but {problem}", r.run)
    for name, v in numbers.items():
        _require(v is None or _finite(v), f"reference.{name}", "null or a finite number", v)
    _require(r.episode_return is None or r.episode_return != 0, "reference.episode_return",
             "null or a nonzero number (it divides the return)", r.episode_return)
    _require(r.cost_rate is None or r.cost_rate > 0, "reference.cost_rate",
             "null or a positive number (it divides the cost rate)", r.cost_rate)
