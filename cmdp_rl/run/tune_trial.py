"""A search's trial (docs/tuning.md): its job's training curve to the study and pruning, its outcome, and the
feasibility rule.

A trial trains ``seeds`` seeds of one set of options in one job (a population, ``population.seeds``). Its value is
the mean over the seeds of the deployed policy's eval return; for each cost, its constraint is ``bound - budget``
with ``bound`` the 95% upper bound of the seeds' mean eval cost (``feasible_by=upper``, the default) or that mean
(``feasible_by=mean``). The upper bound is the default because the search picks the best of many noisy trials: the
trials whose seeds happened to come out cheap are the ones a mean would let through, and their options then go over
budget on new seeds. Optuna's samplers take the constraint as a constraint (``constraints_func``), never as a
penalty on the value.

Inside the job: the sweeper (run/tune_search.py) names the trial in the job's ``hydra.job.env_set``; the Hydra
callback below (``hydra.callbacks`` in configs/config.yaml, a no-op in any other job) then watches the training
loop's rows (``run/loop.py``'s ITERATION_OBSERVERS). Past the warm-up (``hydra.sweeper.prune_after`` of the
iterations), each iteration it reports the mean over the trial's seeds of the training batches' episode return as
Optuna's intermediate value and asks the study's pruner whether to stop. Only the return is reported, so a trial is
never pruned for its cost, which early in training is over budget in most runs that end within it. Nothing before
the warm-up is reported either: early on, a constrained run's return is what it gains by going over budget before its
multiplier rises, and Optuna's median and percentile pruners judge a trial by the best value it ever reported, so an
early over-budget peak would shield a trial that then collapses, and a run that is cautious from the start would be
pruned against the others' peaks (both seen on Reach1D: docs/tuning.md). And the pruner compares the trial with the
finished trials within budget only (:class:`FeasibleOnly`): a return bought by going over budget is no bar to clear.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from cmdp_rl.run.loop import ITERATION_OBSERVERS
from cmdp_rl.run.tune import STORAGE_ENV, STUDY_ENV, TRIAL_ENV

LEVEL = 0.95


class ReportToTrial(Callback):
    """Hydra callback: in a search's job, watch the training loop for its trial."""

    def __init__(self) -> None:
        self.observer: Observer | None = None

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        env = OmegaConf.select(config, "hydra.job.env_set") or {}
        if TRIAL_ENV in env:
            self.observer = Observer(str(env[STORAGE_ENV]), str(env[STUDY_ENV]), int(env[TRIAL_ENV]))
            ITERATION_OBSERVERS.append(self.observer)

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        if self.observer is not None and self.observer in ITERATION_OBSERVERS:  # jobs may share this process
            ITERATION_OBSERVERS.remove(self.observer)
        self.observer = None


class Observer:
    def __init__(self, url: str, study_name: str, number: int) -> None:
        import hydra.utils
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        self.storage = optuna.storages.RDBStorage(url)
        self.study = optuna.load_study(study_name=study_name, storage=self.storage)
        study_id = self.storage.get_study_id_from_name(study_name)
        self.trial_id = self.storage.get_trial_id_from_study_id_trial_number(study_id, number)
        self.number = number
        spec = self.study.user_attrs.get("pruner")
        self.pruner = FeasibleOnly(hydra.utils.instantiate(spec)) if spec else None
        self.prune_after = float(self.study.user_attrs.get("prune_after", 0.0))
        self.reported: set[int] = set()

    def __call__(self, iteration: int, iterations: int, rows: list[dict[str, Any]]) -> None:
        import optuna

        # A population that trains its seeds one after another goes through the iterations once per seed: the
        # first seed's curve is the one reported and judged (a step is reported once).
        returns = [r["episode_return"] for r in rows if not math.isnan(r["episode_return"])]
        if iteration in self.reported or not returns or iteration < math.ceil(self.prune_after * iterations):
            return
        value = sum(returns) / len(returns)
        self.storage.set_trial_intermediate_value(self.trial_id, iteration, value)
        self.reported.add(iteration)
        if self.pruner is not None and self.pruner.prune(self.study, self.storage.get_trial(self.trial_id)):
            raise optuna.TrialPruned(
                f"trial {self.number} at iteration {iteration} of {iterations}: training return {value:.4g} "
                f"is below what {type(self.pruner.inner).__name__} asks of it (against the trials within budget)"
            )


class FeasibleOnly:
    """An Optuna pruner that sees, of the study's finished trials, only those within budget (see the module)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def prune(self, study: Any, trial: Any) -> bool:
        return self.inner.prune(_FeasibleView(study), trial)


class _FeasibleView:
    """The study, its infeasible finished trials left out of ``get_trials`` (which Optuna's median, percentile and
    successive-halving pruners read; the Hyperband pruner reads the storage itself and sees every trial)."""

    def __init__(self, study: Any) -> None:
        self._study = study

    def __getattr__(self, name: str) -> Any:
        return getattr(self._study, name)

    def get_trials(self, deepcopy: bool = True, states: Any = None) -> list[Any]:
        from optuna.trial import TrialState

        trials = self._study.get_trials(deepcopy=deepcopy, states=states)
        return [t for t in trials if t.state != TrialState.COMPLETE or feasible(t)]


def constraints(trial: Any) -> Sequence[float]:
    """Optuna's ``constraints_func``: the trial's ``bound - budget`` per cost (<= 0 is within budget), stored by
    the search when the trial ended. A pruned trial has no deployed policy: its zeros say nothing is known against
    it, so the sampler ranks it with the pruned by its curve, as it would without a constraint."""
    return list(trial.user_attrs["constraint"])


def feasible(trial: Any) -> bool:
    from optuna.trial import TrialState

    return trial.state == TrialState.COMPLETE and all(c <= 0 for c in trial.user_attrs.get("constraint", [1.0]))


def best_feasible(trials: Sequence[Any]) -> Any | None:
    """The finished trial with the highest value among those within every budget (the lowest number on a tie);
    None when none is. An infeasible trial is never the best, whatever its return."""
    ok = [t for t in trials if feasible(t) and t.value is not None]
    return max(ok, key=lambda t: (t.value, -t.number)) if ok else None


def seed_results(job_dir: str | Path) -> list[dict[str, Any]]:
    """Each seed's eval.json in a trial's job directory: a population's agents (population.json lists their
    directories) or, with one seed, the run itself."""
    job = Path(job_dir)
    summary = job / "population.json"
    dirs = [job / r["dir"] for r in json.loads(summary.read_text())["runs"]] if summary.is_file() else [job]
    return [json.loads((d / "eval.json").read_text()) for d in dirs if (d / "eval.json").is_file()]


def outcome(results: Sequence[Mapping[str, Any]], names: Sequence[str], budget: Sequence[float], by: str) -> dict:
    """A finished trial's user attributes from its seeds' eval.json: the mean return and costs over the seeds with
    95% intervals (Student's t over the seeds; with one seed, the run's own bootstrap interval over episodes), the
    95% upper bound of each cost, and the constraint, ``bound - budget`` per cost (``by``: upper or mean)."""
    from cmdp_rl.report.metrics import constraint_name

    k = len(names)
    returns = [float(r["episode_return"]) for r in results]
    ret_ci = list(results[0]["episode_return_ci95"]) if len(results) == 1 else _interval(returns)
    costs, cost_ci, upper = [], [], []
    for c in names:
        values = [float(r[constraint_name("episode_cost", c, k)]) for r in results]
        costs.append(values)
        if len(results) == 1:
            cost_ci.append(list(results[0][constraint_name("episode_cost_ci95", c, k)]))
            upper.append(float(results[0][constraint_name("episode_cost_ucb95", c, k)]))
        else:
            cost_ci.append(_interval(values))
            upper.append(_upper(values))
    mean_cost = [sum(v) / len(v) for v in costs]
    bound = upper if by == "upper" else mean_cost
    return {
        "return": sum(returns) / len(returns),
        "return_ci": ret_ci,
        "returns": returns,
        "cost": mean_cost,
        "cost_ci": cost_ci,
        "cost_upper": upper,
        "costs": costs,
        "constraint": [b - d for b, d in zip(bound, budget)],
    }


def _interval(values: Sequence[float]) -> list[float]:
    from scipy import stats  # here: every run imports this module (its Hydra callback), few of them need scipy

    mean = sum(values) / len(values)
    return [float(b) for b in stats.t.interval(LEVEL, len(values) - 1, loc=mean, scale=stats.sem(values))]


def _upper(values: Sequence[float]) -> float:
    from scipy import stats

    return float(sum(values) / len(values) + stats.t.ppf(LEVEL, len(values) - 1) * stats.sem(values))
