"""A search's trial (docs/tuning.md, "A trial and its verdict" and "Pruning"): its job's training curve to the
study's pruner, its outcome over its seeds, and the feasibility rule (``constraint = bound - budget`` per cost, the
bound by ``feasible_by``), which Optuna's samplers take as a constraint (``constraints_func``), never as a penalty.

Inside a job the search (tune/search.py) names the trial in ``hydra.job.env_set``; ``cmdp-train`` then hands the
training loop :func:`trial_observers`' :class:`Observer` of the job's rows (none in any other job). Past the warm-up
(``prune_after``) it reports the return only, never the cost, and the pruner compares it with the trials within
budget only (:class:`FeasibleOnly`)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

LEVEL = 0.95
TRIAL_ENV = "CMDP_TUNE_TRIAL"  # hydra.job.env_set keys: how a job learns which trial of which study it is
STUDY_ENV = "CMDP_TUNE_STUDY"
STORAGE_ENV = "CMDP_TUNE_STORAGE"


def trial_observers(env_set: Mapping[str, Any] | None) -> list[Observer]:
    """The observers of a job's training loop (``run.loop.Observer``): its trial's, where ``env_set`` (the job's
    ``hydra.job.env_set``) names one; none in any other job."""
    env = env_set or {}
    if TRIAL_ENV not in env:
        return []
    return [Observer(str(env[STORAGE_ENV]), str(env[STUDY_ENV]), int(env[TRIAL_ENV]))]


class Observer:
    """A trial's watch on its job's training loop: each iteration's mean training return to the study's storage,
    and the pruner's verdict on it (``optuna.TrialPruned``, which stops the job)."""

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

        # Seeds trained one after another go through the iterations once each: the first seed's curve is reported.
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
    ret_ci = list(results[0]["episode_return_ci95"]) if len(results) == 1 else _t_bounds(returns)[0]
    costs, cost_ci, upper = [], [], []
    for c in names:
        values = [float(r[constraint_name("episode_cost", c, k)]) for r in results]
        costs.append(values)
        if len(results) == 1:
            ci = list(results[0][constraint_name("episode_cost_ci95", c, k)])
            up = float(results[0][constraint_name("episode_cost_ucb95", c, k)])
        else:
            ci, up = _t_bounds(values)
        cost_ci.append(ci)
        upper.append(up)
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


def _t_bounds(values: Sequence[float]) -> tuple[list[float], float]:
    """Student's t over ``values``: the 95% interval of their mean, and its one-sided 95% upper bound."""
    from scipy import stats  # here: every run imports this module (its Hydra callback), few of them need scipy

    mean, sem, dof = sum(values) / len(values), stats.sem(values), len(values) - 1
    interval = [float(b) for b in stats.t.interval(LEVEL, dof, loc=mean, scale=sem)]
    return interval, float(mean + stats.t.ppf(LEVEL, dof) * sem)
