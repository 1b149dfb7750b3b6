"""Every registered algorithm in every cross-cutting check: a short run, a crash and resume equal to
the uninterrupted run, golden numbers, evaluation without the algorithm, K > 1 costs, Discrete and
MultiDiscrete actions.

The algorithms are the registry's when this file is collected: the built-in ones, and any a test
file collected before this one registers (tests/test_components.py's toy_reinforce), so a new
algorithm joins every check by registering. Each trains with the tiny options its options class
declares beside it (``AlgoConfig.tiny``) on helpers.runs' TINY Reach1D run.
"""

import re
from dataclasses import replace

import pytest
import torch
from helpers.cost_envs import MATCH_ID, MULTI_MATCH_ID, TWO_COST_ID
from helpers.golden import GOLDEN, WRITE, check, outputs
from helpers.resume import assert_same_run, crash_then_resume
from helpers.runs import eval_result, metrics_rows, tiny

from cmdp_rl import evaluate, load_config, train
from cmdp_rl.config import registry
from cmdp_rl.config.registry import component, names
from cmdp_rl.config.run_config import CONFIG_DIR
from cmdp_rl.config.validation import ConfigError
from cmdp_rl.run.checkpoint import load_checkpoint
from cmdp_rl.run.rundir import load_trained
from lab.studies.fork_policy import members_of

ALGOS = names("algo")


def enrolled(algo: str, env: dict | None = None, **top) -> dict:
    """helpers.runs' TINY run with ``algo`` and the tiny options it declares (``env``: another env)."""
    cfg = tiny(**top)
    own = component("algo", algo).options.tiny_env
    if env is not None or own:
        cfg["env"] = dict(env if env is not None else own)
    cfg["algo"] = {"name": algo, **component("algo", algo).options.tiny, "cost_limit": cfg["algo"]["cost_limit"]}
    return cfg


@pytest.mark.parametrize("algo", ALGOS)
def test_evaluation_loads_the_policy_without_building_the_algorithm(algo, tmp_path, monkeypatch, quiet):
    cfg = enrolled(algo, total_steps=64)
    train(load_config(cfg), tmp_path, echo=quiet)

    def forbidden(*args, **kwargs):
        raise AssertionError("evaluation built the algorithm")

    monkeypatch.setitem(registry._REGISTRY["algo"], algo, replace(component("algo", algo), build=forbidden))
    trained = load_trained(tmp_path, num_envs=2)
    state = load_checkpoint(tmp_path / "checkpoint.pt")
    saved = state["members"][0]["algo_state"]["networks"]
    loaded = trained.agent.state_dict()
    if trained.cfg.deploy.policy == "mixture":  # the deployed actor is the chosen snapshots' mixture
        snapshots = state["members"][0]["policy_mixture"]
        weights = snapshots["weights"] or [1.0] * len(snapshots["members"])  # None: uniform, all of them
        chosen = [m for m, w in zip(snapshots["members"], weights) if w > 0]
        members = members_of(trained.agent.actor)
        assert len(members) == len(chosen) and all(
            all(torch.equal(m.state_dict()[k], s[k]) for k in s) for m, s in zip(members, chosen)
        )
        saved = {k: v for k, v in saved.items() if not k.startswith("actor.")}
        loaded = {k: v for k, v in loaded.items() if not k.startswith("actor.")}
    assert saved.keys() == loaded.keys() and all(torch.equal(saved[k], loaded[k]) for k in saved)
    result = evaluate(trained.agent, trained.env, 2, seed=1)
    assert result["episodes"] == 2
    trained.env.close()


@pytest.mark.cpu_kernels
@pytest.mark.parametrize("algo", ALGOS)
def test_crash_then_resume_equals_the_uninterrupted_run(algo, tmp_path, monkeypatch, quiet):
    def crashed_past_the_last_checkpoint(broken) -> None:  # checkpoints at 2 and 4, then row 5
        assert len(metrics_rows(broken)) == 5 and load_checkpoint(broken / "checkpoint.pt")["iteration"] == 4

    cfg = enrolled(algo)
    assert_same_run(*crash_then_resume(cfg, tmp_path, monkeypatch, quiet, checked=crashed_past_the_last_checkpoint))


@pytest.mark.cpu_kernels
@pytest.mark.parametrize("algo", ALGOS)
def test_a_short_run_gives_its_golden_numbers(algo, tmp_path, quiet):
    """A short run writes a row per iteration and a result, and the numbers recorded for
    ``registry_<algo>`` (as test_golden.py: exactly a recording of this or another machine, else the
    first recording within its cross-machine tolerance). An algorithm with no recording is checked
    for the first part and then skipped with how to record one."""
    name = f"registry_{algo}"
    result = train(load_config(enrolled(algo)), tmp_path, echo=quiet)
    rows = metrics_rows(tmp_path)
    assert [r["iteration"] for r in rows] == [str(i) for i in range(1, 8)]
    assert result["episodes"] == 4 and eval_result(tmp_path)["episodes"] == 4
    assert all(r["cost_limit"] == "0.2" and r["lagrange_multiplier"] != "" for r in rows)
    if not (GOLDEN / f"{name}.json").exists() and not WRITE:
        pytest.skip(
            f"no golden numbers for {algo}: CMDP_RL_WRITE_GOLDEN=1 python -m pytest tests/test_registry_enrolment.py -k {algo}"
        )
    check(name, outputs(tmp_path))


def _takes(algo: str) -> int | None:
    return component("algo", algo).options.constraints


@pytest.mark.parametrize("algo", ALGOS)
def test_two_costs_train_with_a_budget_each_or_stop_in_one_line(algo, tmp_path, quiet):
    two_costs = {"name": "gym", "id": TWO_COST_ID, "num_envs": 2, "max_steps": 8, "kwargs": {"length": 4}}
    cfg = enrolled(algo, env=two_costs)
    cfg.update(total_steps=64, checkpoint_every=100)
    cfg["algo"]["cost_limit"] = [2.0, 5.0]
    if component("algo", algo).options.envs is not None:  # an algorithm for other envs says so
        with pytest.raises(ConfigError, match=rf"^env must be .* with algo={algo}, got 'gym'$"):
            train(load_config(cfg), tmp_path / "run", echo=quiet)
        assert not (tmp_path / "run").exists()
    elif _takes(algo) is None:
        train(load_config(cfg), tmp_path, echo=quiet)
        header = (tmp_path / "metrics.csv").read_text().splitlines()[0].split(",")
        assert {"episode_cost/hazard_a", "episode_cost/hazard_b", "cost_limit/hazard_b"} <= set(header)
    else:
        with pytest.raises(ConfigError, match=rf"for an env with 2 costs \(hazard_a, hazard_b\).*got '{algo}'") as err:
            train(load_config(cfg), tmp_path / "run", echo=quiet)
        assert not (tmp_path / "run").exists()
        # The line names the toolkit's algorithms that take the env (a test's own registrations aside).
        named = str(err.value).split(" for an env")[0].removeprefix("algo must be ").replace(" or ", ", ").split(", ")
        builtin = [a for a in ALGOS if (CONFIG_DIR / "algo" / f"{a}.yaml").is_file()]
        takes = [a for a in builtin if _takes(a) is None and component("algo", a).options.envs is None]
        assert "\n" not in str(err.value) and named == sorted(takes)


@pytest.mark.parametrize("env_id", [MATCH_ID, MULTI_MATCH_ID])
@pytest.mark.parametrize("algo", ALGOS)
def test_discrete_actions_train_or_stop_in_one_line(algo, env_id, tmp_path, quiet):
    cfg = enrolled(algo, env={"name": "gym", "id": env_id, "num_envs": 2, "max_steps": 8})
    cfg.update(total_steps=64, checkpoint_every=100, eval_episodes=2)
    try:
        result = train(load_config(cfg), tmp_path / "run", echo=quiet)
    except ConfigError as exc:  # an algorithm that cannot act on categories says so, naming a field
        assert re.fullmatch(r"(algo|env|policy)[\w.]* must [^\n]+", str(exc)), exc
        assert not (tmp_path / "run" / "metrics.csv").exists()
        return
    assert result["episodes"] == 2 and len(metrics_rows(tmp_path / "run")) == 2
