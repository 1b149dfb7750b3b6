"""Run directories written before the agent model (commit 6e31f3c: the ``ActorCritic`` triple,
other parameter names) still evaluate and resume.

The fixtures (tests/fixtures/old_runs/, made as ``record_reference.py`` there says): short runs of
ppo_lag with the mlp, lstm and transformer policies and of cpo (mlp, observation normalization), on
Reach1D with 10-step episodes, so that episodes end in every batch (J_c is then the same number
before and after the shared estimate, and a resumed run's numbers are comparable). Each holds what
the old code gave: ``eval.json``, ``reference.pt`` (a deterministic and a sampled rollout of the
loaded networks with both critics' values) and ``resumed_metrics.csv`` (``metrics.csv`` after
resuming the run to 192 steps).

Their checkpoints are of format 2, which only Python's full unpickler reads: each test loads them
the way a user would, after saying they trust them: ``trust_checkpoint=true`` or the converter
(``python -m cmdp_rl.run.convert``); by default they are refused.

The fixtures were recorded on an AMD EPYC (AVX2). Another CPU sums floats in another order, so a
resumed row matches them within :data:`RESUMED` (see there), not bit for bit; whether a
resume continues a run exactly on one machine is ``tests/test_resume.py``'s bit-exact comparison.
"""

import csv
import json
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch
import yaml
from helpers.golden import CROSS_CPU
from helpers.tolerance import Tolerance, assert_close, record, share

from cmdp_rl import Collector, keys, train
from cmdp_rl.cli import evaluate as evaluate_cli  # the command's main in-process: no interpreter per fixture
from cmdp_rl.config.saved import deploy_node
from cmdp_rl.population import population
from cmdp_rl.population.resume import resume_population
from cmdp_rl.run.checkpoint import FORMAT_VERSION, UnsafeCheckpointError, load_checkpoint
from cmdp_rl.run.convert import convert_run
from cmdp_rl.run.migrations import is_legacy, saved_config_nodes
from cmdp_rl.run.resume import resume_config
from cmdp_rl.run.rundir import load_trained

# Every test here compares with numbers an AMD EPYC recorded: make test-cpus reruns them all.
pytestmark = pytest.mark.cpu_kernels

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "fixtures" / "old_runs"
RUNS = ["mlp", "lstm", "transformer", "cpo"]
STEPS, SEED = 24, 11  # as record_reference.py
# Columns that measure the machine, not the run.
TIMING = {"sps", "time_s"}
# The fixtures were recorded on an AMD EPYC (AVX2); these compare with them. Measured: on an Intel Xeon (AVX-512),
# 2026-11-25, the resumed row's numbers differed by at most 4.9e-6 relative (transformer's loss_pi, -0.0137374) and
# 1.2e-7 absolute (cpo's entropy, -1.41192); under make test-cpus' settings, 2026-12-07, the largest difference
# used 5% of RESUMED (transformer, sse4), 3% of OUTPUTS (the transformer's values), 1.5% of RETURNS and 15% of
# VARIANTS (the last bit of a float32 action near 0.1). One update's sums in another order move no more than that,
# while a change of the algorithm, the restored state or the generators moves these numbers by percents (a wrong
# optimizer state or generator draws other minibatches). RESUMED's abs covers numbers that are exactly 0 on one
# machine and 1e-12 on another.
RESUMED = Tolerance("old runs: a resumed row, recorded on another CPU", rel=1e-4, abs=1e-9)
OUTPUTS = Tolerance("old runs: converted networks' outputs, recorded on another CPU", rel=1e-5, abs=1e-5)
RETURNS = Tolerance("old runs: re-evaluated returns, recorded on another CPU", rel=0.0, abs=1e-6)
VARIANTS = Tolerance("old runs: converted variants' actions, recorded on another CPU", rel=0.0, abs=1e-7)


def _copy(name: str, tmp_path: Path, convert: bool = False) -> Path:
    """A copy of the fixture ``name``; with ``convert``, its checkpoint converted to the current
    format by the converter (the old file kept beside it)."""
    run = tmp_path / name
    shutil.copytree(FIXTURES / name, run)
    if convert:
        convert_run(run, echo=lambda _: None)
        assert (run / "checkpoint.pt.format2").is_file()
        assert load_checkpoint(run / "checkpoint.pt")["format"] == FORMAT_VERSION  # safely, now
    return run


def _run(script: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, script, *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


def _same_number(new: str, old: str, tol: Tolerance = RESUMED) -> bool:
    """Two metrics.csv cells: equal text, or numbers within ``tol``."""
    if new == old:
        return True
    try:
        used = share(float(new), float(old), tol)
    except ValueError:
        return False
    record(tol, used)
    return used <= 1.0


def _rows(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("name", RUNS)
def test_fixture_is_an_old_checkpoint(name):
    """The fixtures really hold the old parameter names (else the tests below prove nothing), in a
    format the safe load refuses unless trusted."""
    with pytest.raises(UnsafeCheckpointError, match="older cmdp_rl format.*trust_checkpoint=true"):
        load_checkpoint(FIXTURES / name / "checkpoint.pt")
    state = load_checkpoint(FIXTURES / name / "checkpoint.pt", trust=True)
    assert state["format"] == 2
    assert is_legacy(state["algo_state"]["networks"])
    assert any(k.startswith("actor.module.") for k in state["algo_state"]["networks"])


@pytest.mark.parametrize("name", RUNS)
def test_converted_networks_give_the_old_outputs(name, tmp_path):
    """The loaded agent (the run converted by the converter, then loaded safely) acts and values as
    the old networks did: same distribution parameters and actions, deterministic and sampled, and
    the same values of both critics."""
    reference = torch.load(FIXTURES / name / "reference.pt")
    for mode, ref in reference.items():
        trained = load_trained(_copy(name, tmp_path / mode, convert=True), num_envs=2)
        agent = trained.agent
        torch.manual_seed(SEED)
        batch = Collector(trained.env, agent, STEPS, seed=SEED, deterministic=mode == "deterministic").collect()
        for signal in ("reward", "cost"):
            values, next_values = agent.rollout_values(batch, signal)
            value_key = keys.SIGNALS[signal][1]
            assert_close(values, ref[value_key], OUTPUTS, f"{mode} {signal}")
            assert_close(next_values, ref[f"{keys.NEXT}/{value_key}"], OUTPUTS, f"{mode} {signal}")
        for k in (keys.LOC, keys.SCALE, keys.ACTION):
            assert_close(batch[k], ref[k], OUTPUTS, f"{mode} {k}")
        trained.env.close()


@pytest.mark.parametrize("name", RUNS)
def test_evaluate_reproduces_the_old_eval_json(name, tmp_path):
    """Through the trusted path (``trust_checkpoint=true``); refused without it."""
    run = _copy(name, tmp_path)
    out = tmp_path / "again.json"
    assert evaluate_cli.main([f"run={run}", f"output={out}"]) == 2 and not out.exists()
    assert evaluate_cli.main([f"run={run}", f"output={out}", "trust_checkpoint=true"]) == 0
    old, new = json.loads((run / "eval.json").read_text()), json.loads(out.read_text())
    assert new["episodes"] == old["episodes"] == 4
    for k in ("episode_return", "episode_return_std", "episode_return_min", "episode_return_max"):
        assert_close(new[k], old[k], RETURNS, k)
    for k in ("episode_cost", "episode_cost_min", "episode_cost_max", "episode_length", "goal_reached"):
        assert new[k] == old[k], k


@pytest.mark.parametrize("name", RUNS)
def test_resume_continues_the_old_run(name, tmp_path):
    """Resuming to 192 steps writes one more metrics row, the one the old code wrote when resumed
    the same way, to the last bits another CPU moves (RESUMED; the J_c estimate is the same
    here: episodes end in every batch):
    networks, optimizer states, multiplier, collector and generators all came back. One fixture
    resumes through ``train.py`` (``trust_checkpoint=true``), one after the converter, the others
    through the trusted path in this process."""
    run = _copy(name, tmp_path, convert=name == "lstm")
    before = _rows(run / "metrics.csv")
    if name == "mlp":  # the command itself, once
        proc = _run("train.py", f"resume={run}", "total_steps=192", "trust_checkpoint=true")
        assert proc.returncode == 0, proc.stderr[-3000:]
    elif name == "lstm":  # converted: a plain resume
        train(resume_config(run, {"total_steps": 192}, ["total_steps"]), echo=lambda _: None)
    else:  # what `train.py resume=<run> total_steps=192 trust_checkpoint=true` runs, in this process
        requested = {"total_steps": 192, "trust_checkpoint": True}
        train(resume_config(run, requested, list(requested)), echo=lambda _: None)
    rows = _rows(run / "metrics.csv")
    assert len(before) == 2 and len(rows) == 3
    assert [r["step"] for r in rows] == ["64", "128", "192"]
    assert rows[:2] == before
    old = _rows(FIXTURES / name / "resumed_metrics.csv")[2]
    new = rows[2]
    common = sorted(set(old) & set(new) - TIMING)
    assert {"loss_v", "loss_vc", "episode_return", "lagrange_multiplier"} <= set(common)
    assert set(old) == set(new)
    for k in common:  # the same numbers, but for the last bits another CPU moves
        assert _same_number(new[k], old[k]), (k, new[k], old[k])
    state = load_checkpoint(run / "checkpoint.pt")
    assert state["step"] == 192 and not is_legacy(state["members"][0]["algo_state"]["networks"])


def test_converted_variants_act_as_before():
    """Policy variants the runs above do not cover (record_variants.py: the MLP with its input
    encoder, observation normalization, GRU, two-layer LSTM and transformer): the converted
    networks give the old deterministic actions."""
    from cmdp_rl import load_config, make_agent, make_env
    from cmdp_rl.rollout.normalization import make_normalizers
    from cmdp_rl.run.migrations import convert_networks

    variants = torch.load(FIXTURES / "variants.pt")
    assert len(variants) == 5
    for name, old in variants.items():
        cfg = load_config(old["overrides"])
        env = make_env(cfg.env)
        torch.manual_seed(123)  # other initial parameters than the old ones: only the loaded ones count
        agent = make_agent(cfg.policy, env, make_normalizers(cfg, env))
        agent.load_state_dict(convert_networks(old["networks"], agent))
        loc = Collector(env, agent, 16, seed=1, deterministic=True).collect()[keys.LOC]
        assert old["loc"].std() > 1e-4, name  # actions that vary: a wrong mapping would show
        assert_close(loc, old["loc"], VARIANTS, name)


# Format 3 (tests/fixtures/format3/record.py, the code of commit 1509f63): a run's checkpoint held its
# one entry at the top level, a population's population.pt one entry per agent under "agents".
FORMAT3 = ROOT / "tests" / "fixtures" / "format3"


def _format3(name: str, tmp_path: Path) -> Path:
    run = tmp_path / name
    shutil.copytree(FORMAT3 / name, run)
    return run


@pytest.mark.parametrize("name", ["run", "population/agents/001_seed=1"])
def test_a_format_3_run_evaluates_safely_to_its_eval_json(name, tmp_path):
    """A format 3 run (and a population agent's directory) loads with the safe unpickler, no trust
    asked, and evaluates to the numbers its own code wrote (its deployed mixture included)."""
    run = tmp_path / "run"
    shutil.copytree(FORMAT3 / name, run)
    saved = torch.load(run / "checkpoint.pt", weights_only=True)
    assert saved["format"] == 3 and "algo_state" in saved and "members" not in saved  # else this proves nothing
    assert "policy_mixture" in saved
    out = tmp_path / "again.json"
    assert evaluate_cli.main([f"run={run}", f"output={out}"]) == 0
    old, new = json.loads((run / "eval.json").read_text()), json.loads(out.read_text())
    for k in ("episodes", "episode_return", "episode_return_std", "episode_cost", "episode_length"):
        assert_close(new[k], old[k], RESUMED, k)


def _four_iterations(rows: list[dict], whole: list[dict]) -> None:
    """Two iterations trained on the recording CPU and two resumed here from its checkpoint, against four trained
    here: training on other kernels, as a golden case is, so within the golden numbers' CROSS_CPU."""
    assert [r["step"] for r in rows] == [r["step"] for r in whole] == ["64", "128", "192", "256"]
    for row, expected in zip(rows, whole):
        for k in sorted(set(expected) - TIMING):
            assert _same_number(row[k], expected[k], CROSS_CPU), (row["iteration"], k, row[k], expected[k])


def test_a_format_3_run_resumes_into_an_uninterrupted_run(tmp_path):
    """Resumed from its format 3 checkpoint (iteration 2) to four iterations, without trust: the rows
    of a run trained four iterations at once by this code (last bits: another CPU recorded it)."""
    run = _format3("run", tmp_path)
    train(resume_config(run, {"total_steps": 256}, ["total_steps"]), echo=lambda _: None)
    cfg = resume_config(run, {}, [])
    whole = tmp_path / "whole"
    train(replace(cfg, resume=None, total_steps=256), whole, echo=lambda _: None)
    _four_iterations(_rows(run / "metrics.csv"), _rows(whole / "metrics.csv"))
    assert load_checkpoint(run / "checkpoint.pt")["format"] == FORMAT_VERSION


def test_a_format_3_population_resumes_into_an_uninterrupted_population(tmp_path):
    """A format 3 population (population.pt: one entry per agent under "agents") resumed to four
    iterations, without trust, gives each agent the rows of a population trained four iterations at
    once by this code; its checkpoint is then the current layout, one member per agent."""
    pop = _format3("population", tmp_path)
    assert "agents" in torch.load(pop / "population.pt", weights_only=True)  # else this proves nothing
    train(resume_population(pop, {"total_steps": 256}, ["total_steps"]), pop, echo=lambda _: None)
    # its config names the deployment and multiplier options flat, as before their nodes: as its resume reads it
    raw = deploy_node(saved_config_nodes(yaml.safe_load((FORMAT3 / "population" / "population.yaml").read_text())))
    raw["algo"]["advantage_scale"] = "raw"  # as its agents recorded (ppo_lag's default became standardized since)
    whole = tmp_path / "whole"
    train(population({**raw, "total_steps": 256}), whole, echo=lambda _: None)
    for a, b in zip(sorted((whole / "agents").iterdir()), sorted((pop / "agents").iterdir())):
        _four_iterations(_rows(b / "metrics.csv"), _rows(a / "metrics.csv"))
    state = load_checkpoint(pop / "checkpoint.pt")  # a run's name, the old file superseded
    assert state["format"] == FORMAT_VERSION and len(state["members"]) == 2 and "agents" not in state
    assert not (pop / "population.pt").exists()
