"""The search's ask-and-tell loop (``hydra/sweeper=cmdp_optuna``, docs/tuning.md): ask Optuna for trials, launch
each as one Hydra job through the configured ``hydra/launcher``, tell Optuna each trial's return and, as its
constraint, its costs against the budgets (:mod:`cmdp_rl.run.tune`).

Not ``study.optimize``, which runs the objective in its own process and threads while a Hydra job runs where its
launcher puts it; what ``optimize`` adds is done here with Optuna's public pieces: heartbeats while a trial runs
(a killed worker's trial is failed and queued again) and ``n_trials`` counted across every worker on the storage.
"""

from __future__ import annotations

import os
import socket
import sys
import threading
import time
import warnings
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any, Iterator

from cmdp_rl.run.tune import (
    STORAGE_ENV,
    STUDY_ENV,
    TRIAL_ENV,
    Settings,
    TuneError,
    budgets,
    check_space,
    open_storage,
    override,
    parse_space,
)
from cmdp_rl.run.tune_trial import constraints, outcome, seed_results

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
            from cmdp_rl.run.tune_report import report

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
            trial.set_user_attr("overrides", task)
            trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
            trial.set_user_attr("job_dir", str(self.sweep_dir / _subdir(trial.number)))
            env = {TRIAL_ENV: str(trial.number), STUDY_ENV: self.s.study_name, STORAGE_ENV: self.url}
            jobs.append(
                [*task, f"hydra.sweep.subdir={_subdir(trial.number)}"]
                + [f"++hydra.job.env_set.{k}={_quote(v)}" for k, v in env.items()]
            )
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
            trial.set_user_attr("constraint", [0.0] * len(self.budget))  # see tune.constraints
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
        from cmdp_rl.run.tune_report import trial_line

        print(f"tune: {trial_line(self.storage.get_trial(self._trial_id(trial)), self.budget)}")
        return True


def _subdir(number: int) -> str:
    return f"trial_{number:04d}"


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
