"""The constrained hyperparameter search behind ``hydra/sweeper=cmdp_optuna`` (docs/tuning.md): its input, checked
before anything runs (the space, the settings, the budgets, the storage), and the ask-and-tell loop that launches
each trial as one Hydra job through the configured ``hydra/launcher`` and tells Optuna its return and, as its
constraint, its costs against the budgets. A trial's side (its curve to the pruner, its outcome, the feasibility
rule) is :mod:`cmdp_rl.tune.trial`; the report :mod:`cmdp_rl.tune.report`.

Not ``study.optimize``, which runs the objective in its own process and threads while a Hydra job runs where its
launcher puts it; what ``optimize`` adds is done here with Optuna's public pieces: heartbeats while a trial runs
(a killed worker's trial is failed and queued again) and ``n_trials`` counted across every worker on the storage."""

from __future__ import annotations

import math
import os
import re
import socket
import sys
import threading
import time
import warnings
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Iterator, Mapping, Sequence

from cmdp_rl.config.validation import ConfigError, per_constraint
from cmdp_rl.tune.trial import STORAGE_ENV, STUDY_ENV, TRIAL_ENV, constraints, outcome, seed_results

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
    """Compose (``compose(overrides)``: a job's task config, resolved) and validate a job at each end of the space: an
    option the config lacks, or a value its rules refuse, stops here in one line. Returns the low end's config."""
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
    """The env's cost names (a 2-env copy of the base config's env is built: only the env knows them) and the search's
    budget per cost: ``budget`` (a number, a list of K, or ``{cost: budget}`` naming every cost), or, when null, the
    config's own ``algo.cost_limit`` (the task's unless given), unless that is among the ``searched`` options."""
    from cmdp_rl.config.run_config import load_config
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


SETTLED = ("COMPLETE", "PRUNED")
# What a resumed or second worker must share with the study's first: a trial's value means the same only then.
SHARED = ("fixed", "seeds", "budget", "cost_names", "feasible_by")


def sweep(sweeper: Any, arguments: list[str]) -> list[Any]:
    """The sweeper's ``sweep``: bad input stops in one line (exit 2) before any job; then the loop, the report."""
    try:
        search = Search(sweeper, arguments)
    except TuneError as exc:
        print(f"tune: {exc}", file=sys.stderr)
        sys.exit(2)
    return search.run()


def _compose(sweeper: Any, overrides: list[str]) -> dict:
    """A job's task config as Hydra composes it for ``overrides``, resolved."""
    from omegaconf import OmegaConf, open_dict

    cfg = sweeper.hydra_context.config_loader.load_sweep_config(sweeper.config, overrides)
    with open_dict(cfg):
        del cfg["hydra"]
    return OmegaConf.to_container(cfg, resolve=True)


def _built(setting: str, build: Any) -> Any:
    """``build()``, or what it raises (a bad ``_target_`` or arguments) as one line naming the setting."""
    try:
        return build()
    except Exception as exc:  # noqa: BLE001 - whatever the target raises
        raise TuneError(f"hydra.sweeper.{setting}: {str(exc).splitlines()[0]}") from None


def _quote(text: str) -> str:
    """A value of any characters as one Hydra override value."""
    return "'" + text.replace("\\", "\\\\").replace("'", "\\'") + "'"


class Search:
    def __init__(self, sweeper: Any, arguments: list[str]) -> None:
        import hydra.utils
        import optuna
        from omegaconf import OmegaConf

        # Optuna marks constraints_func, heartbeats and their retry as experimental, and heartbeats outside
        # study.optimize as unusual: this search uses them on purpose (see the module), so it says so once, here.
        warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
        warnings.filterwarnings("ignore", message="Heartbeat of storage is supposed to be used with Study.optimize")
        options = OmegaConf.to_container(OmegaConf.create(sweeper.options), resolve=True)
        self.s = Settings.of(options)
        self.launcher = sweeper.launcher
        self.sweep_dir = Path(str(sweeper.config.hydra.sweep.dir)).absolute()
        params = [f"{k}={v}" for k, v in (options.get("params") or {}).items()]
        self.space, self.fixed = parse_space(params + list(arguments))
        raw = check_space(self.space, self.fixed, self.s.seeds, partial(_compose, sweeper))
        self.cost_names, self.budget = budgets(self.s.budget, raw, list(self.space))
        self.base_seed = int(raw.get("seed", 0))
        sampler = self._sampler(hydra.utils.instantiate)
        if self.s.pruner is not None:  # built here too, so that a bad spec stops before any job (the job builds it)
            _built("pruner", lambda: hydra.utils.instantiate(self.s.pruner))
        self.url = self.s.storage or f"sqlite:///{self.sweep_dir / 'study.db'}"
        if self.s.storage is None:
            self.sweep_dir.mkdir(parents=True, exist_ok=True)
        self.storage = open_storage(self.url, self.s.heartbeat_s, self.s.grace_s)
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self.study = optuna.create_study(
            study_name=self.s.study_name,
            storage=self.storage,
            sampler=sampler,
            direction="maximize",
            load_if_exists=True,
        )
        self._share()

    def _sampler(self, instantiate: Any) -> Any:
        import inspect

        import optuna
        from hydra.utils import get_class

        spec = dict(self.s.sampler)
        cls = _built("sampler", lambda: get_class(spec["_target_"]))
        if "constraints_func" in inspect.signature(cls).parameters:
            spec["constraints_func"] = constraints
        elif cls is not optuna.samplers.RandomSampler:  # random search ignores values and constraints alike
            raise TuneError(
                f"hydra.sweeper.sampler {cls.__name__} takes no constraints_func, and the budget is a constraint: "
                "use TPESampler, NSGAIISampler or GPSampler (or RandomSampler)"
            )
        return _built("sampler", lambda: instantiate(spec))

    def _share(self) -> None:
        """Record what the study's trials mean (or check it against what they meant when it began), and what its
        jobs need to prune: the pruner and the warm-up."""
        mine = {
            "fixed": self.fixed,
            "seeds": [self.base_seed + i for i in range(self.s.seeds)],
            "budget": self.budget,
            "cost_names": list(self.cost_names),
            "feasible_by": self.s.feasible_by,
        }
        have = self.study.user_attrs
        for key in SHARED:
            if key in have and have[key] != mine[key]:
                raise TuneError(
                    f"study {self.s.study_name!r} in {self.url} was started with {key} {have[key]}, this command "
                    f"has {mine[key]}: give another hydra.sweeper.study_name, or the study's own settings"
                )
        for key, value in {**mine, "pruner": self.s.pruner, "prune_after": self.s.prune_after}.items():
            self.study.set_user_attr(key, value)

    def _count(self, below: int | None = None) -> tuple[int, int]:
        """The settled (complete or pruned) and the running trials, of those numbered below ``below`` if given."""
        trials = [t for t in self.study.get_trials(deepcopy=False) if below is None or t.number < below]
        return sum(t.state.name in SETTLED for t in trials), sum(t.state.name == "RUNNING" for t in trials)

    def run(self) -> list[Any]:
        from optuna.storages import fail_stale_trials

        done, failures, waited = [], 0, False
        print(f"tune: study {self.s.study_name!r} in {self.url}, {self.s.n_trials} trials of {self.s.seeds} seeds")
        while True:
            fail_stale_trials(self.study)  # a killed worker's trial: failed, and queued again by the retry callback
            settled, running = self._count()
            if settled >= self.s.n_trials:
                break
            room = self.s.n_trials - settled - running
            if room <= 0:  # the rest runs on other workers (or is a killed worker's, until its heartbeat is stale)
                if not waited:
                    print(f"tune: waiting for {running} trial(s) running elsewhere")
                waited = True
                time.sleep(self.s.heartbeat_s)
                continue
            batch = [self.study.ask(self.space) for _ in range(min(self.s.n_jobs, room))]
            batch = [t for t in batch if not self._surplus(t)]
            if not batch:
                continue
            for ret, trial in zip(self._launch(batch), batch):
                ok = self._tell(trial, ret)
                done.append(ret)
                failures = 0 if ok else failures + 1
            if failures > self.s.max_failures:
                print(f"tune: {failures} trials failed in a row; stopping (their error.txt says why)", file=sys.stderr)
                sys.exit(1)
        if self.s.report:
            from cmdp_rl.tune.report import report

            print(report(self.study, self.sweep_dir))
        return done

    def _surplus(self, trial: Any) -> bool:
        """Two workers may both see room for the last trial: the later-numbered one is surplus, failed unrun."""
        from optuna.trial import TrialState

        if sum(self._count(below=trial.number)) < self.s.n_trials:
            return False
        trial.set_user_attr("error", "surplus: n_trials already asked for by other workers")
        self.study.tell(trial, state=TrialState.FAIL)
        return True

    def _launch(self, batch: list[Any]) -> list[Any]:
        jobs = []
        for trial in batch:
            task = [*self.fixed, *(override(k, self.space[k], v) for k, v in trial.params.items())]
            task.append(f"population.seeds={self.s.seeds}")
            subdir = f"trial_{trial.number:04d}"
            trial.set_user_attr("overrides", task)
            trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
            trial.set_user_attr("job_dir", str(self.sweep_dir / subdir))
            env = {TRIAL_ENV: str(trial.number), STUDY_ENV: self.s.study_name, STORAGE_ENV: self.url}
            env_set = [f"++hydra.job.env_set.{k}={_quote(v)}" for k, v in env.items()]
            jobs.append([*task, f"hydra.sweep.subdir={subdir}", *env_set])
        ids = [self._trial_id(t) for t in batch]
        with _heartbeats(self.storage, ids, self.s.heartbeat_s):
            return list(self.launcher.launch(jobs, initial_job_idx=batch[0].number))

    def _trial_id(self, trial: Any) -> int:
        study_id = self.storage.get_study_id_from_name(self.s.study_name)
        return self.storage.get_trial_id_from_study_id_trial_number(study_id, trial.number)

    def _tell(self, trial: Any, ret: Any) -> bool:
        """Tell Optuna how the trial's job ended; True unless it failed."""
        import optuna
        from optuna.trial import TrialState

        try:
            ret.return_value  # a failed job's exception, raised again
            error = None
        except Exception as exc:  # noqa: BLE001 - any job failure is the trial's
            error = exc
        job_dir = Path(str(ret.hydra_cfg.hydra.runtime.output_dir)) if ret.hydra_cfg else None
        if isinstance(error, optuna.TrialPruned):
            trial.set_user_attr("constraint", [0.0] * len(self.budget))  # see trial.constraints
            self.study.tell(trial, state=TrialState.PRUNED)
            print(f"tune: trial {trial.number} pruned: {error}")
            return True
        results = seed_results(job_dir) if error is None and job_dir else []
        if error is None and len(results) != self.s.seeds:
            error = RuntimeError(f"{len(results)} of {self.s.seeds} seeds left an eval.json in {job_dir}")
        if error is not None:
            trial.set_user_attr("error", f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}")
            self.study.tell(trial, state=TrialState.FAIL)
            print(f"tune: trial {trial.number} failed: {trial.user_attrs['error']}", file=sys.stderr)
            return False
        attrs = outcome(results, self.cost_names, self.budget, self.s.feasible_by)
        for key, value in attrs.items():
            trial.set_user_attr(key, value)
        self.study.tell(trial, attrs["return"])
        from cmdp_rl.tune.report import trial_line

        print(f"tune: {trial_line(self.storage.get_trial(self._trial_id(trial)), self.budget)}")
        return True


@contextmanager
def _heartbeats(storage: Any, trial_ids: list[int], interval: int) -> Iterator[None]:
    """Record the trials' heartbeats while their jobs run (Optuna beats only inside ``study.optimize``)."""
    stop = threading.Event()

    def beat() -> None:
        while True:
            for trial_id in trial_ids:
                storage.record_heartbeat(trial_id)
            if stop.wait(interval):
                return

    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
