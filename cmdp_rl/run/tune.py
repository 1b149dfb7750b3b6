"""The constrained hyperparameter search behind ``hydra/sweeper=cmdp_optuna`` (docs/tuning.md): what it is given,
checked before anything runs (the space, the settings, the budgets, the storage). The ask-and-tell loop over Hydra's
launcher is :mod:`cmdp_rl.run.tune_search`; a trial (its training curve to the pruner, its outcome, the feasibility
rule) :mod:`cmdp_rl.run.tune_trial`; the report :mod:`cmdp_rl.run.tune_report`.
"""

from __future__ import annotations

import math
import re
import time
import warnings
from types import SimpleNamespace
from typing import Any, Callable, Mapping, Sequence

from cmdp_rl.config.validation import ConfigError

TRIAL_ENV = "CMDP_TUNE_TRIAL"  # hydra.job.env_set keys: how a job learns which trial of which study it is
STUDY_ENV = "CMDP_TUNE_STUDY"
STORAGE_ENV = "CMDP_TUNE_STORAGE"
RESERVED = ("seed", "population")  # the search sets these itself (the seeds of a trial)


class TuneError(ConfigError):
    """Bad input to the search: one line, before anything runs."""


class Settings(SimpleNamespace):
    """``hydra.sweeper.*`` as hydra_plugins/cmdp_tune/sweeper.py's ``ConstrainedOptunaConf`` declares them, checked."""

    @classmethod
    def of(cls, options: Mapping[str, Any]) -> Settings:
        s = cls(**options)
        for name in ("n_trials", "seeds", "n_jobs", "heartbeat_s"):
            _require(isinstance(getattr(s, name), int) and getattr(s, name) >= 1, f"hydra.sweeper.{name}", ">= 1", s)
        _require(s.feasible_by in ("upper", "mean"), "hydra.sweeper.feasible_by", "upper or mean", s)
        _require(0 <= s.prune_after < 1, "hydra.sweeper.prune_after", "a fraction in [0, 1)", s)
        _require(s.grace_s > s.heartbeat_s, "hydra.sweeper.grace_s", "more than heartbeat_s", s)
        _require(s.max_failures >= 0, "hydra.sweeper.max_failures", ">= 0", s)
        _require(bool(s.study_name), "hydra.sweeper.study_name", "a name", s)
        return s


def _require(ok: bool, field: str, allowed: str, s: Settings) -> None:
    if not ok:
        raise TuneError(f"{field} must be {allowed}, got {getattr(s, field.rsplit('.', 1)[1])!r}")


def parse_space(arguments: Sequence[str]) -> tuple[dict[str, Any], list[str]]:
    """The searched options (``key=interval(a,b)``, ``tag(log,interval(a,b))``, ``range(a,b[,step])`` as Hydra
    counts it, stop excluded, ``choice(...)``) as Optuna distributions, and the other overrides as they are. A
    later override of a key replaces an earlier one (the command line after ``hydra.sweeper.params``)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

    try:
        parsed = OverridesParser.create().parse_overrides(list(arguments))
    except HydraException as exc:
        raise TuneError(str(exc).splitlines()[0]) from None
    space: dict[str, Any] = {}
    fixed: dict[str, str] = {}
    for ov in parsed:
        key = ov.key_or_group
        if key.split(".")[0] in RESERVED and not (key == "seed" and not ov.is_sweep_override()):
            raise TuneError(f"{ov.input_line}: {key} is the search's own (hydra.sweeper.seeds seeds from seed)")
        space.pop(key, None)
        fixed.pop(key, None)
        if not ov.is_sweep_override():
            fixed[key] = ov.input_line
            continue
        if ov.is_add() or ov.is_delete() or ov.is_force_add():
            raise TuneError(f"{ov.input_line}: a searched option must be one the config has (no +, ++ or ~)")
        value = ov.value()
        if ov.is_choice_sweep():
            choices = [_text(x) for x in ov.sweep_iterator()]
            if not choices:
                raise TuneError(f"{ov.input_line}: an empty choice")
            space[key] = CategoricalDistribution(choices)
        elif ov.is_range_sweep():
            values = list(ov.sweep_iterator())
            if not values or getattr(value, "shuffle", False):
                raise TuneError(f"{ov.input_line}: an empty range" if not values else f"{ov.input_line}: shuffle")
            kind = IntDistribution if all(isinstance(v, int) for v in values) else FloatDistribution
            space[key] = kind(values[0], values[-1], step=value.step if value.step is not None else 1)
        else:  # an interval, log-scaled with tag(log, ...)
            low, high, log = value.start, value.end, "log" in value.tags
            if not low < high:
                raise TuneError(f"{ov.input_line}: an empty range (low {low} is not below high {high})")
            if log and low <= 0:
                raise TuneError(f"{ov.input_line}: a log scale needs low > 0, got {low}")
            both_int = isinstance(low, int) and isinstance(high, int)
            space[key] = (IntDistribution if both_int else FloatDistribution)(low, high, log=log)
    return space, list(fixed.values())


def _text(value: Any) -> str:
    """A choice as its override text: Optuna keeps it as a string, the job's override gets it verbatim (a list or
    a group choice such as ``sweep/ppo_lag`` included)."""
    from hydra.core.override_parser.types import Transformer

    return value if isinstance(value, str) else Transformer.str(value)


def override(key: str, dist: Any, value: Any) -> str:
    """The override that gives ``key`` the sampled ``value``; floats in full (the rerun command repeats them)."""
    from optuna.distributions import CategoricalDistribution

    return f"{key}={value}" if isinstance(dist, CategoricalDistribution) else f"{key}={value!r}"


def corners(space: Mapping[str, Any]) -> list[list[str]]:
    """The space's low and high ends, every option at once, as overrides: what a check composes and validates."""
    ends = {k: (d.choices[0], d.choices[-1]) if hasattr(d, "choices") else (d.low, d.high) for k, d in space.items()}
    return [[override(k, d, ends[k][end]) for k, d in space.items()] for end in (0, 1)]


def check_space(
    space: Mapping[str, Any], fixed: Sequence[str], seeds: int, compose: Callable[[list[str]], dict]
) -> dict[str, Any]:
    """Compose and validate a job at each end of the space (an option the config lacks, or a value its rules
    refuse, stops here in one line); returns the low end's config. ``compose(overrides)`` is Hydra's composition
    of a job's task config, resolved."""
    from cmdp_rl.config.run_config import load_config
    from cmdp_rl.population.spec import agent_configs

    if not space:
        raise TuneError("nothing to search: give hydra.sweeper.params or key=interval(...) / choice(...) options")
    raw_low: dict[str, Any] = {}
    for name, ends in zip(("low", "high"), corners(space)):
        overrides = [*fixed, *ends, f"population.seeds={seeds}"]
        try:
            raw = compose(overrides)
        except Exception as exc:  # noqa: BLE001 - Hydra's composition errors have no common base to name
            first = str(exc).splitlines()[0]
            unknown = re.match(r"Could not override '([^']+)'", first)
            causes = [str(exc)]
            while exc.__cause__ is not None or exc.__context__ is not None:  # Hydra's reason is in the chain
                exc = exc.__cause__ or exc.__context__
                causes.append(str(exc))
            if unknown and any("not in struct" in c for c in causes):
                raise TuneError(f"{unknown[1]} is not an option of this config ({first})") from None
            raise TuneError(f"cannot compose a trial at the space's {name} end ({' '.join(ends)}): {first}") from None
        try:
            agent_configs(raw) if seeds > 1 else load_config(raw)
        except ConfigError as exc:
            raise TuneError(f"the space's {name} end ({' '.join(ends)}): config error: {exc}") from None
        raw_low = raw_low or raw
    return raw_low


def budgets(budget: Any, raw: Mapping[str, Any], searched: Sequence[str] = ()) -> tuple[tuple[str, ...], list[float]]:
    """The env's cost names (a 2-env copy of the base config's env is built: only the env knows them) and the
    search's budget per cost: ``budget`` (a number, a list of K, or ``{cost: budget}`` naming every cost), or,
    when null, the config's own ``algo.cost_limit`` (the task's unless given), unless that is among the
    ``searched`` options."""
    from cmdp_rl.config.run_config import load_config
    from cmdp_rl.config.validation import per_constraint
    from cmdp_rl.envs import make_env

    if budget is None and "algo.cost_limit" in searched:
        raise TuneError("algo.cost_limit is searched, so it is no budget to judge trials by: give hydra.sweeper.budget")
    cfg = load_config({k: v for k, v in raw.items() if k != "population"})
    env = make_env(cfg.env, num_envs=min(2, cfg.env.num_envs), device=cfg.device)
    try:
        names = tuple(env.cost_names)
    finally:
        env.close()
    if budget is None:
        return names, per_constraint(cfg.algo.cost_limit, "algo.cost_limit", names)
    costs = f"(the env's costs: {', '.join(names)})"
    if isinstance(budget, Mapping):
        unknown = [n for n in budget if n not in names]
        if unknown:
            raise TuneError(f"hydra.sweeper.budget has a cost the env lacks, {unknown[0]!r} {costs}")
        given = dict(budget)
    elif isinstance(budget, (int, float)):
        given = dict.fromkeys(names, budget)
    else:
        if len(list(budget)) > len(names):
            raise TuneError(f"hydra.sweeper.budget has {len(list(budget))} values for {len(names)} costs {costs}")
        given = dict(zip(names, budget))
    missing = [n for n in names if n not in given]
    if missing:
        raise TuneError(f"hydra.sweeper.budget has no value for cost {missing[0]!r} {costs}")
    values = [given[n] for n in names]
    if not all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 for v in values):
        raise TuneError(f"hydra.sweeper.budget must be numbers >= 0, got {budget!r}")
    return names, [float(v) for v in values]


def open_storage(url: str, heartbeat_s: int, grace_s: int) -> Any:
    """Optuna's RDB storage at ``url``, with heartbeats: a trial whose worker stops beating (killed) is failed
    after ``grace_s`` and queued again with the same options (Optuna's retry callback)."""
    import optuna

    # Optuna 4.9 renamed the stale-trial callback; the older name is the only one before it.
    retry = getattr(optuna.storages, "RetryHeartbeatStaleTrialCallback", None)
    kw = "heartbeat_stale_trial_callback" if retry else "failed_trial_callback"
    retry = retry or optuna.storages.RetryFailedTrialCallback
    for attempt in range(3):
        try:
            with warnings.catch_warnings():  # heartbeats and their retry are marked experimental; used on purpose
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                return optuna.storages.RDBStorage(
                    url, heartbeat_interval=heartbeat_s, grace_period=grace_s, **{kw: retry(max_retry=3)}
                )
        except Exception as exc:  # noqa: BLE001 - SQLAlchemy's and the drivers' errors have no common base
            # Workers started together on a new database all create its tables; the slower ones' inserts fail
            # (a duplicate row, a table that already exists, a lock), and a second attempt finds the tables made.
            if attempt < 2 and re.search(r"UNIQUE constraint|already exists|duplicate key|locked", str(exc)):
                time.sleep(1.0)
                continue
            raise TuneError(f"cannot open storage {_safe(url)}: {str(exc).splitlines()[0]}") from None


def _safe(url: str) -> str:
    try:
        from sqlalchemy.engine import make_url

        return make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001 - an unparsable URL is shown as given
        return url
