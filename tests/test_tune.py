"""The constrained hyperparameter search (hydra/sweeper=cmdp_optuna, docs/tuning.md): bad input stops in one line,
the feasibility rule (an infeasible trial is never the best, whatever its return), the report, the pruner that
ignores cost and infeasible trials, a search killed mid-trial that resumes without running anything twice, and two
workers that share one study."""

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

optuna = pytest.importorskip("optuna")
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from optuna.distributions import FloatDistribution
from optuna.trial import TrialState, create_trial

from cmdp_rl.tune.report import main as report_main
from cmdp_rl.tune.report import report
from cmdp_rl.tune.search import Settings, TuneError, budgets, check_space, open_storage, parse_space, sweep
from cmdp_rl.tune.trial import FeasibleOnly, Observer, best_feasible, outcome

ROOT = Path(__file__).resolve().parents[1]
# A search of 4 trials of a second or two: 2 seeds, one iteration of 16 envs (one pass over the batch), a 4-episode
# evaluation of the last iterate.
TINY = [
    "+tune=ppo_lag",
    "env=reach1d_torch",
    "env.num_envs=16",
    "total_steps=2048",
    "algo.update_epochs=1",
    "eval_episodes=4",
    "deploy.policy=last",
    "log_interval=1000",
    "hydra.sweeper.n_trials=4",
    "hydra.sweeper.seeds=2",
    "hydra.sweeper.heartbeat_s=1",
    "hydra.sweeper.grace_s=2",
    "hydra.sweeper.report=false",
]


def _compose(overrides: list[str]) -> dict:
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        return OmegaConf.to_container(compose("config", overrides=list(overrides)), resolve=True)


def _error(call, *args) -> str:
    with pytest.raises(TuneError) as info:
        call(*args)
    message = str(info.value)
    assert "\n" not in message, message
    return message


@pytest.mark.parametrize(
    "space, expected",
    [
        ("algo.lr=interval(0.1,0.01)", "an empty range (low 0.1 is not below high 0.01)"),
        ("algo.update_epochs=range(4,2)", "an empty range"),
        ("algo.lr=tag(log,interval(0,0.1))", "a log scale needs low > 0"),
        ("seed=choice(1,2)", "the search's own"),
        ("population.seeds=choice(1,2)", "the search's own"),
        ("+algo.foo=interval(0,1)", "must be one the config has"),
    ],
)
def test_a_bad_space_is_one_line(space, expected):
    assert expected in _error(parse_space, ["env=reach1d", space])


def test_space_options_budgets_storage_and_settings_are_checked_before_anything_runs(tmp_path, capsys):
    space, fixed = parse_space(["env=reach1d", "algo.lr=tag(log,interval(1e-4,1e-2))", "algo.update_epochs=range(2,6)"])
    assert fixed == ["env=reach1d"] and space["algo.update_epochs"].high == 5  # range() as Hydra counts it
    assert space["algo.lr"].log and check_space(space, fixed, 2, _compose)["algo"]["lr"] == 1e-4
    unknown, _ = parse_space(["algo.lrr=interval(0.1,0.2)"])
    assert "algo.lrr is not an option of this config" in _error(check_space, unknown, [], 1, _compose)
    refused, _ = parse_space(["algo.gamma=interval(0.9,1.0)"])  # the high end is one the option's rules refuse
    assert "algo.gamma must be in [0, 1), got 1.0" in _error(check_space, refused, [], 1, _compose)

    grid = _compose(["env=grid"])  # two costs: hazard_a, hazard_b
    assert budgets(None, grid)[0] == ("hazard_a", "hazard_b")
    assert "no value for cost 'hazard_b'" in _error(budgets, {"hazard_a": 1.0}, grid)
    assert "no value for cost 'hazard_b'" in _error(budgets, [1.0], grid)
    assert budgets({"hazard_a": 0.5, "hazard_b": 2}, grid)[1] == [0.5, 2.0]
    assert "give hydra.sweeper.budget" in _error(budgets, None, grid, ["algo.cost_limit"])  # searched: no budget

    assert "cannot open storage" in _error(open_storage, "sqlite:////proc/no/such/dir/study.db", 1, 2)
    assert "cannot open storage" in _error(open_storage, "nosuchdb://user@host/db", 1, 2)
    assert "hydra.sweeper.n_trials must be >= 1" in _error(Settings.of, {**_settings(), "n_trials": 0})

    class Sweeper:  # the sweeper's entry point: one line on stderr, exit 2, nothing else done
        options = {**_settings(), "feasible_by": "median"}

    with pytest.raises(SystemExit) as info:
        sweep(Sweeper(), [])
    assert info.value.code == 2
    assert capsys.readouterr().err == "tune: hydra.sweeper.feasible_by must be upper or mean, got 'median'\n"


def _settings() -> dict:
    from hydra_plugins.cmdp_tune.sweeper import ConstrainedOptunaConf

    return {k: v for k, v in vars(ConstrainedOptunaConf()).items() if not k.startswith("_")}


def _eval(ret: float, cost: float) -> dict:
    return {
        "episode_return": ret,
        "episode_return_ci95": [ret - 0.01, ret + 0.01],
        "episode_cost": cost,
        "episode_cost_ci95": [cost * 0.5, cost * 1.5],
        "episode_cost_ucb95": cost * 1.4,
    }


def test_a_trial_is_within_budget_by_its_costs_upper_bound_over_seeds():
    seeds = [_eval(0.30, 0.2), _eval(0.32, 0.9), _eval(0.34, 0.95)]  # mean cost 0.683, spread over seeds
    upper, mean = outcome(seeds, ["cost"], [1.0], "upper"), outcome(seeds, ["cost"], [1.0], "mean")
    t = 2.919986  # Student's t, 2 degrees of freedom, one-sided 95%
    sd = math.sqrt(sum((c - 0.68333) ** 2 for c in (0.2, 0.9, 0.95)) / 2)
    assert upper["cost_upper"][0] == pytest.approx(0.68333 + t * sd / math.sqrt(3), rel=1e-4)
    assert upper["constraint"][0] > 0 > mean["constraint"][0]  # over budget by its bound, within by its mean
    assert upper["return"] == pytest.approx(0.32) and upper["return_ci"][0] < 0.32 < upper["return_ci"][1]
    one = outcome([_eval(0.3, 0.8)], ["cost"], [1.0], "upper")  # one seed: the run's own bootstrap bound
    assert one["cost_upper"] == [pytest.approx(1.12)] and one["constraint"][0] == pytest.approx(0.12)


def _study(tmp_path: Path, trials: list[tuple[float, float]]) -> "optuna.Study":
    tmp_path.mkdir(exist_ok=True)
    study = optuna.create_study(study_name="t", storage=f"sqlite:///{tmp_path / 'study.db'}", direction="maximize")
    for key, value in {"budget": [1.0], "cost_names": ["cost"], "seeds": [0, 1, 2], "feasible_by": "upper"}.items():
        study.set_user_attr(key, value)
    for i, (ret, cost) in enumerate(trials):
        attrs = outcome([_eval(ret, cost)] * 2 + [_eval(ret + 0.002, cost)], ["cost"], [1.0], "upper")
        lr = 1e-3 * (i + 1)
        attrs["overrides"] = ["+tune=ppo_lag", "env=reach1d_torch", f"algo.lr={lr!r}", "population.seeds=3"]
        study.add_trial(
            create_trial(
                value=attrs["return"],
                params={"algo.lr": lr},
                distributions={"algo.lr": FloatDistribution(1e-4, 1e-1)},
                user_attrs=attrs,
            )
        )
    return study


def test_the_report_names_the_best_trial_within_budget_never_a_higher_infeasible_one(tmp_path, capsys):
    study = _study(tmp_path, [(0.50, 3.0), (0.30, 0.2), (0.20, 0.0), (0.45, 1.1)])  # 0 and 3 over budget
    assert best_feasible(study.trials).number == 1
    text = report(study, tmp_path)
    assert "4 trials finished (4 complete, 0 pruned), 0 failed; 2 of 4 within budget" in text
    assert "best within budget: trial 1" in text and "options: algo.lr=0.002" in text
    assert "return 0.3007, 95% CI [0.2978, 0.3035]" in text and "budget 1: within" in text
    assert "rerun:        python train.py +tune=ppo_lag env=reach1d_torch algo.lr=0.002 population.seeds=3" in text
    assert (
        "on new seeds: python train.py +tune=ppo_lag env=reach1d_torch algo.lr=0.002 population.seeds=3 seed=3" in text
    )
    summary = json.loads((tmp_path / "tune.json").read_text())
    assert summary["best"]["trial"] == 1 and summary["within_budget"] == 2
    assert [t["within_budget"] for t in summary["trials"]] == [False, True, True, False]
    for name in ("history.png", "importances.png", "front.png"):
        assert (tmp_path / name).stat().st_size > 10_000, name
    report_main([str(tmp_path / "study.db"), "--no-plots"])  # the same report again, from the storage
    assert "best within budget: trial 1" in capsys.readouterr().out

    over = _study(tmp_path / "over", [(0.5, 3.0), (0.4, 1.2)])
    text = report(over, tmp_path / "over", plots=False)
    assert "no trial is within budget: none is reported as best" in text and "best within budget" not in text
    assert json.loads((tmp_path / "over" / "tune.json").read_text())["best"] is None


def test_the_pruner_judges_the_return_against_trials_within_budget_and_only_after_the_warm_up(tmp_path):
    study = _study(tmp_path, [])
    dist = {"algo.lr": FloatDistribution(1e-4, 1e-1)}
    for ret, cost in ((1.0, 5.0), (0.2, 0.1)):  # a high curve bought over budget, a low one within it
        attrs = outcome([_eval(ret, cost)] * 3, ["cost"], [1.0], "upper")
        curve = {1: ret, 2: ret, 3: ret}
        study.add_trial(
            create_trial(
                value=ret, params={"algo.lr": 1e-3}, distributions=dist, user_attrs=attrs, intermediate_values=curve
            )
        )
    study.set_user_attr("pruner", {"_target_": "optuna.pruners.MedianPruner", "n_startup_trials": 1})
    study.set_user_attr("prune_after", 0.3)
    running = study.ask()
    running.report(0.5, 1)
    plain = optuna.pruners.MedianPruner(n_startup_trials=1)
    frozen = study.trials[running.number]
    assert plain.prune(study, frozen) and not FeasibleOnly(plain).prune(study, frozen)  # median 0.6 vs 0.2

    hopeless = study.ask()
    observe = Observer(f"sqlite:///{tmp_path / 'study.db'}", "t", hopeless.number)
    low = [{"episode_return": 0.1, "episode_cost": 50.0}, {"episode_return": 0.1, "episode_cost": 50.0}]
    observe(2, 10, low)  # below the feasible trial's curve, but inside the warm-up (3 of 10 iterations): unreported
    with pytest.raises(optuna.TrialPruned):
        observe(3, 10, low)
    assert study.trials[hopeless.number].intermediate_values == {3: 0.1}  # the return, never the cost


def _search(sweep_dir: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, str(ROOT / "train.py"), "-m", *TINY, *extra, f"hydra.sweep.dir={sweep_dir}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _trials(sweep_dir: Path) -> list:
    return optuna.load_study(study_name="ppo_lag_reach1d", storage=f"sqlite:///{sweep_dir / 'study.db'}").trials


def test_two_workers_share_a_study_and_a_worker_killed_mid_trial_loses_nothing(tmp_path):
    """Two workers start on one new SQLite study; the one that asks for the third trial (so it has finished one) is
    killed with SIGKILL while that trial trains. The other resumes the study as a restarted search would (the killed
    trial, silent past the grace period, is failed and queued again with its options) and the two have finished
    n_trials between them, none run twice. One test for all of it: each process pays seconds of imports."""
    # On a quiet machine the premise can fail by timing: a trial trains in about a second, so the third may finish
    # between its directory appearing and the kill (seen once in a fresh clone's run), or one worker, started
    # seconds before the other, may finish the first two trials alone so that the victim has finished none. Then
    # the two workers start again on a new study (at most five times); trials 16 times the others' length widen
    # both windows.
    for attempt in range(5):
        sweep = tmp_path / f"attempt_{attempt}"
        workers = {w.pid: w for w in (_search(sweep, "total_steps=32768"), _search(sweep, "total_steps=32768"))}
        deadline = time.monotonic() + 180
        while not (sweep / "trial_0002").is_dir():  # its job has started, so its worker and options are recorded
            assert all(w.poll() is None for w in workers.values()) and time.monotonic() < deadline, _output(workers)
            time.sleep(0.01)
        trials = _trials(sweep)
        killed = trials[2]
        owner = killed.user_attrs["worker"]
        if killed.state == TrialState.RUNNING and any(t.user_attrs.get("worker") == owner for t in trials[:2]):
            victim = workers.pop(int(killed.user_attrs["worker"].rsplit(":", 1)[1]))
            victim.send_signal(signal.SIGKILL)
            victim.wait()
            break
        _output(workers)  # stops both
    else:
        pytest.fail("five times, the third trial finished before the kill, or its worker had finished no trial before")
    before = {p: p.stat().st_mtime_ns for p in sweep.glob("trial_*/agents/*/eval.json")}
    (survivor,) = workers.values()
    out = survivor.communicate(timeout=240)[0]
    assert survivor.returncode == 0, out[-3000:]

    trials = _trials(sweep)
    settled = [t for t in trials if t.state in (TrialState.COMPLETE, TrialState.PRUNED)]
    assert len(settled) == 4  # n_trials over both workers, not 4 each
    assert len({t.user_attrs["worker"] for t in settled}) == 2  # both finished trials
    assert trials[2].state == TrialState.FAIL  # its heartbeat stopped: failed, never counted, and run again
    (retry,) = [t for t in trials if t.system_attrs.get("failed_trial") == 2]
    assert retry.state == TrialState.COMPLETE and retry.params == trials[2].params
    assert before and all(p.stat().st_mtime_ns == m for p, m in before.items())  # finished trials ran once
    ran = sorted(p.parent.parent.parent.name for p in sweep.glob("trial_*/agents/*/eval.json"))
    assert ran == sorted(2 * [f"trial_{t.number:04d}" for t in settled])  # each settled trial's 2 seeds, once


def _output(workers: dict) -> str:
    for w in workers.values():
        w.kill()
    return "\n".join(w.communicate()[0][-2000:] for w in workers.values())
