"""Population training (cmdp_rl/population/): agent i of a population trains as its single run
does, the population resumes after a kill, bad or unsupported configs stop in one line."""

import copy
import json
import math
import shutil
from pathlib import Path

import pytest
import torch
import yaml
from helpers.runs import eval_result, metrics_rows, run_script, tiny
from helpers.tolerance import Tolerance, assert_close, record, share

from cmdp_rl import ConfigError, load_config, train
from cmdp_rl.config.registry import component
from cmdp_rl.population import population
from cmdp_rl.population.resume import resume_population
from cmdp_rl.population.spec import agent_configs, batched_algos, stacked, unbatched
from cmdp_rl.report.sweeps import find_runs
from cmdp_rl.run.checkpoint import CheckpointError
from cmdp_rl.run.migrations import saved_config_defaults
from cmdp_rl.run.ownership import RunDirTaken
from cmdp_rl.run.rundir import load_trained

# Not bit for bit: the population's Adam (population/stacked.py) rounds differently from torch's fused
# kernel (about 1e-7 after 20 steps) and per-agent reductions (advantage moments, gradient norms)
# sum in another order; a few iterations carry these last-bit differences further. Measured on 2026-12-07, on this
# CPU and under make test-cpus' settings: at most 1.9e-4 relative (or 1.9e-7 absolute near zero) but for pcpo, whose
# projection steps (coefficients near 90) amplify them to 8.8e-4 relative here (episode_return, 0.0052) and 1.0e-3
# under sse4 (entropy, 0.547). Relative 3e-3 is three times that; episode counts, costs, steps and multipliers come
# out equal.
POPULATION = Tolerance("a population's agent against its single run", rel=3e-3, abs=1e-6)
# One batch of P N worlds or P batches of N: the same arithmetic on arrays of another length, whose lidar may take
# other kernels (tests/test_safe_nav_speed.py's LIDAR: float64 readings 3.2e-14 apart at most), then rounded to the
# float32 observation: one float32 rounding step (1.2e-7 relative) where a reading lies that close to a rounding
# boundary. Measured equal under every make test-cpus setting; 2.5e-7 relative covers one rounding step twice over.
WORLDS = Tolerance("safe_nav worlds in one batch or one per agent", rel=2.5e-7, abs=1e-12)


def torch_tiny(**overrides) -> dict:
    return tiny(env={"backend": "torch", "num_envs": 4, "stagger": True}, total_steps=4 * 64, **overrides)


def assert_same_outputs(a, b, where: str) -> None:
    if isinstance(b, dict):
        assert set(a) == set(b), where
        for k in b:
            assert_same_outputs(a[k], b[k], f"{where}.{k}")
    elif isinstance(b, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_outputs(x, y, f"{where}[{i}]")
    elif isinstance(b, float) or (isinstance(b, str) and _is_float(b)):
        used = share(float(a), float(b), POPULATION)
        record(POPULATION, used)
        assert used <= 1.0, f"{where}: {a} != {b} ({used:.3g} of {POPULATION})"
    else:
        assert a == b, where


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _population(tmp_path: Path, raw: dict, name: str = "pop") -> Path:
    out = tmp_path / name
    train(population(raw), out, echo=lambda s: None)
    return out


@pytest.mark.cpu_kernels
@pytest.mark.parametrize(
    "algo, grid, agents",
    [
        # ppo_lag: the budget and the start distribution per agent (a range draws, a fixed start does not).
        ({"name": "ppo_lag"}, {"algo": {"cost_limit": [0.2, 0.5]}, "env": {"start": [[0.3, 0.48], 0.1]}}, [0, 3]),
        ({"name": "penalty", "penalty": 1.0}, {"algo": {"penalty": [0.5, 2.0], "lr": [3e-4, 1e-3]}}, [3]),
        (
            {"name": "pid_lag", "multiplier": {"kind": "pid", "kp": 1.0, "ki": 0.2}},
            {"algo": {"multiplier": {"kp": [0.5, 2.0]}}, "env": {"obs_noise": [0.05]}},
            [1],
        ),
        # Options of the newly batched algorithms per agent: each agent's own algorithm object reads them.
        ({"name": "focops"}, {"algo": {"multiplier": {"lr": [0.1, 0.5], "max": [0.5]}}}, [1]),
        ({"name": "crpo"}, {"algo": {"tolerance": [0.0, 1.0]}}, [0, 1]),
        # What an agent deploys, as its run: the average of its last iterates' actors, and a mixture of
        # snapshots with uniform weights (ppo_lag above: deploy.policy=auto, its feasible mixture).
        ({"name": "pid_lag", "deploy": {"policy": "average"}}, {"algo": {"cost_limit": [0.2, 0.5]}}, [0, 1]),
        (
            {"name": "focops", "deploy": {"policy": "mixture", "weights": "uniform"}},
            {"algo": {"multiplier": {"lr": [0.5]}}},
            [0],
        ),
    ],
)
def test_agent_trains_as_its_single_run(tmp_path, algo, grid, agents):
    algo = dict(algo)
    top = {"deploy": algo.pop("deploy")} if "deploy" in algo else {}
    raw = torch_tiny(algo=algo, eval_deterministic=algo["name"] != "penalty", **top)  # penalty: sampled evaluation
    if algo["name"] != "ppo_lag" and "multiplier" not in algo:  # TINY's pinned node is ppo_lag's
        del raw["algo"]["multiplier"]
    raw["population"] = {"seeds": 1, "grid": grid}
    pop = _population(tmp_path, raw)
    dirs = sorted((pop / "agents").iterdir())
    for i in agents:
        cfg = load_config(yaml.safe_load((dirs[i] / "config.yaml").read_text()))
        single = tmp_path / f"single{i}"
        train(cfg, single, echo=lambda s: None)
        rows, expected = metrics_rows(dirs[i]), metrics_rows(single)
        assert len(rows) == len(expected) == 4
        assert_same_outputs(rows, expected, f"agent {i} metrics")
        assert_same_outputs(eval_result(dirs[i]), eval_result(single), f"agent {i} eval")
    deployed = top.get("deploy", {}).get("policy", {"ppo_lag": "mixture", "penalty": "last"}.get(algo["name"]))
    assert deployed is None or eval_result(dirs[0])["final_policy"] == deployed  # the option is exercised


# Options that make an algorithm's own arithmetic act in a tiny run: FOCOPS's multiplier and its
# KL mask, CRPO's switch (a budget it overspends), CUP's nu in its projection, Sauté's budget state.
ALGO_OPTIONS = {
    "focops": {"multiplier": {"lr": 0.5}, "target_kl": 0.005},
    "crpo": {"tolerance": 0.0},
    "cup": {"multiplier": {"lr": 0.5}},
    "saute": {"unsafe_reward": -0.5},
}


def _tiny_algo(name: str) -> dict:
    """A tiny run's options: a PPO's two epochs of two minibatches, another algorithm's own tiny
    options (``AlgoConfig.tiny``), and what makes its own arithmetic act (ALGO_OPTIONS)."""
    own = {"update_epochs": 2, "num_minibatches": 2} if stacked(name) else component("algo", name).options.tiny
    return {"name": name, **own, **ALGO_OPTIONS.get(name, {})}


@pytest.mark.cpu_kernels
@pytest.mark.parametrize("name", batched_algos())
def test_every_batched_algorithm_trains_as_its_single_runs(tmp_path, name):
    """Enumerated from the registry: each algorithm a population accepts, two agents with their own
    budget and seed, each equal to ``train()`` on its own config.yaml."""
    raw = torch_tiny()
    raw["algo"] = _tiny_algo(name)
    raw["population"] = {"seeds": 1, "grid": {"algo": {"cost_limit": [0.05, 0.5]}, "seed": [3]}}
    pop = _population(tmp_path, raw)
    for i, d in enumerate(sorted((pop / "agents").iterdir())):
        cfg = load_config(yaml.safe_load((d / "config.yaml").read_text()))
        single = tmp_path / f"single{i}"
        train(cfg, single, echo=lambda s: None)
        rows, expected = metrics_rows(d), metrics_rows(single)
        assert len(rows) == len(expected) == 4
        assert_same_outputs(rows, expected, f"{name} agent {i} metrics")
        assert_same_outputs(eval_result(d), eval_result(single), f"{name} agent {i} eval")


def _fork(name: str) -> dict:
    """A tiny run on the fork (envs/fork/): Discrete actions, and two costs for an algorithm that
    takes K > 1 constraints (its options' ``constraints`` is None), else one."""
    k = 2 if component("algo", name).options.constraints is None else 1
    return {
        "env": {"name": "fork", "num_envs": 4, "num_costs": k},
        "algo": _tiny_algo(name),
        "rollout_steps": 16,
        "total_steps": 4 * 64,
        "checkpoint_every": 2,
        "eval_episodes": 4,
        "log_interval": 1,
    }


@pytest.mark.cpu_kernels
@pytest.mark.parametrize("name", batched_algos())
def test_every_batched_algorithm_trains_as_its_single_runs_on_discrete_actions_and_two_costs(tmp_path, name):
    """Enumerated from the registry, on the fork (a Discrete action; K = 2 costs where the algorithm
    takes them, each agent's env its single run's, population.envs.AgentEnvs): each agent equal to
    ``train()`` on its own config.yaml."""
    raw = _fork(name)
    raw["population"] = {"seeds": 1, "grid": {"algo": {"cost_limit": [0.05, 0.5]}, "seed": [3]}}
    pop = _population(tmp_path, raw)
    k = raw["env"]["num_costs"]
    for i, d in enumerate(sorted((pop / "agents").iterdir())):
        cfg = load_config(yaml.safe_load((d / "config.yaml").read_text()))
        single = tmp_path / f"single{i}"
        train(cfg, single, echo=lambda s: None)
        rows, expected = metrics_rows(d), metrics_rows(single)
        assert len(rows) == len(expected) == 4
        assert ("episode_cost/hazard_b" in rows[0]) == (k == 2)  # one column per constraint
        assert_same_outputs(rows, expected, f"{name} agent {i} metrics")
        assert_same_outputs(eval_result(d), eval_result(single), f"{name} agent {i} eval")


@pytest.mark.cpu_kernels
def test_safe_nav_agents_are_one_batch_of_worlds_stepping_as_their_single_runs(tmp_path):
    """env=safe_nav: P N worlds in one env (its options' population_env), agent i's world j seeded
    as its single run's: the worlds step as each agent's own N-world env under the same actions,
    resets included (the same physics, rewards, costs and ends; observations within :data:`WORLDS`),
    and the population trains into one run directory per agent. Its
    agents are not compared with their single runs: the batched forward pass (baddbmm) rounds
    differently from nn.Linear in the last bit on these 60 inputs, and MuJoCo's contacts amplify
    that within one rollout (docs/population.md, measured there)."""
    import importlib.util

    if importlib.util.find_spec("safety_gymnasium") is None or importlib.util.find_spec("mujoco") is None:
        pytest.skip("Safety-Gymnasium is installed by `make setup-safety-gym`")  # as tests/test_safe_nav.py
    from cmdp_rl.envs import make_env
    from cmdp_rl.envs.vector import Step
    from cmdp_rl.population.envs import population_env

    raw = {
        "env": {"name": "safe_nav", "num_envs": 2, "max_steps": 40},
        "algo": {"name": "ppo_lag", "update_epochs": 2, "num_minibatches": 2},
        "normalize": {"obs": False},
        "rollout_steps": 32,
        "total_steps": 128,
        "eval_episodes": 1,
        "log_interval": 1,
    }
    raw["population"] = {"seeds": 2, "grid": {"algo": {"cost_limit": [5.0, 25.0]}}}
    _, cfgs = agent_configs(raw)
    env = population_env(cfgs, 2, [c.seed for c in cfgs], torch.device("cpu"))
    assert type(env).__name__ == "SafeNavVecEnv" and env.num_envs == 8  # one batch of worlds, not AgentEnvs
    own = [make_env(c.env) for c in cfgs]
    first = torch.cat([e.reset(seed=c.seed) for e, c in zip(own, cfgs)])
    assert_close(env.reset(), first, WORLDS, "reset")
    gen = torch.Generator().manual_seed(0)
    for _ in range(90):  # past the 40-step episodes' resets
        actions = [torch.rand(2, 2, generator=gen) * 2 - 1 for _ in own]
        steps = [e.step(a) for e, a in zip(own, actions)]
        for field, joint, *each in zip(Step._fields, env.step(torch.cat(actions)), *steps):
            if field.endswith("obs"):
                assert_close(joint, torch.cat(each), WORLDS, field)
            else:  # the physics is MuJoCo's per world, its rewards differences of two-axis distances: exact
                assert torch.equal(joint, torch.cat(each)), field
    env.close()
    pop = _population(tmp_path, raw)
    runs = find_runs(pop)
    assert len(runs) == 4 and {r.status for r in runs} == {"ok"}
    for d in sorted((pop / "agents").iterdir()):
        rows = metrics_rows(d)
        assert [int(r["step"]) for r in rows] == [64, 128] and all(math.isfinite(float(r["loss_v"])) for r in rows)
        assert math.isfinite(eval_result(d)["episode_return"])


@pytest.mark.cpu_kernels
def test_an_agent_s_own_env_takes_its_own_options(tmp_path):
    """On an env stepped as each agent's own (the fork), the env's grid fields are each agent's:
    agents with their own end probability and goal reward equal their single runs."""
    raw = _fork("ppo_lag")
    raw["population"] = {"seeds": 1, "grid": {"env": {"end_prob": [0.05, 0.2], "goal_reward": [5.0]}}}
    pop = _population(tmp_path, raw)
    dirs = sorted((pop / "agents").iterdir())
    for i, d in enumerate(dirs):
        cfg = load_config(yaml.safe_load((d / "config.yaml").read_text()))
        assert (cfg.env.end_prob, cfg.env.goal_reward) == ([0.05, 0.2][i], 5.0)
        single = tmp_path / f"single{i}"
        train(cfg, single, echo=lambda s: None)
        assert_same_outputs(metrics_rows(d), metrics_rows(single), f"agent {i} metrics")
        assert_same_outputs(eval_result(d), eval_result(single), f"agent {i} eval")
    assert metrics_rows(dirs[0]) != metrics_rows(dirs[1])  # the options acted


def test_the_ppo_family_is_batched():
    assert {"ppo", "penalty", "ppo_lag", "pid_lag", "crpo", "focops", "cup", "saute"} == {
        n for n in batched_algos() if stacked(n)
    }
    assert {"cpo", "pcpo", "trpo_lag"} <= set(batched_algos())  # their own updates, envs and acting batched


@pytest.mark.cpu_kernels
@pytest.mark.parametrize(
    "algo",
    [
        # KL early stopping as a per-agent mask: a limit some agents reach in some iterations.
        {"name": "ppo", "target_kl": 0.002, "update_epochs": 4},
        # Annealed rates per agent, on each agent's own clock.
        {"name": "ppo_lag", "anneal_lr": True},
    ],
)
def test_per_agent_schedules_match_single_runs(tmp_path, algo):
    raw = torch_tiny(algo=algo)
    if algo["name"] != "ppo_lag":
        del raw["algo"]["multiplier"]
    raw["population"] = {"seeds": 2, "grid": {"algo": {"lr": [3e-4, 3e-3]}}}
    pop = _population(tmp_path, raw)
    for i, d in enumerate(sorted((pop / "agents").iterdir())):
        cfg = load_config(yaml.safe_load((d / "config.yaml").read_text()))
        single = tmp_path / f"single{i}"
        train(cfg, single, echo=lambda s: None)
        assert_same_outputs(metrics_rows(d), metrics_rows(single), f"agent {i} metrics")
        assert_same_outputs(eval_result(d), eval_result(single), f"agent {i} eval")


def test_population_outputs_are_runs(tmp_path):
    raw = torch_tiny()
    raw["population"] = {"seeds": 2, "grid": {"algo": {"cost_limit": [0.2, 0.5]}}}
    pop = _population(tmp_path, raw)
    runs = find_runs(pop)  # the sweep readers see the agents, not the population's own directory
    assert len(runs) == 4 and {r.status for r in runs} == {"ok"}
    assert sorted((r.get("algo.cost_limit"), r.get("seed")) for r in runs) == [(0.2, 0), (0.2, 1), (0.5, 0), (0.5, 1)]
    summary = yaml.safe_load((pop / "population.json").read_text())
    assert summary["agents"] == 4 and summary["steps_per_agent"] == 256 and summary["summed_steps_per_s"] > 0
    # its checkpoint is named as a run's, so evaluating its directory as a run's names what it is
    with pytest.raises(CheckpointError, match="is a population; its agents' runs are under"):
        load_trained(pop)


def test_each_agent_logs_to_its_own_tensorboard_directory(tmp_path):
    """logger=tensorboard: each agent's directory opens its log as a single run's (run.start.open_run),
    its scalars those of its metrics.csv."""
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    raw = torch_tiny(logger={"name": "tensorboard"})
    raw["population"] = {"seeds": 1, "grid": {"algo": {"cost_limit": [0.05, 0.5]}}}
    pop = _population(tmp_path, raw)
    for d in sorted((pop / "agents").iterdir()):
        acc = EventAccumulator(str(d / "tb"))
        acc.Reload()
        logged = [(e.step, e.value) for e in acc.Scalars("lagrange_multiplier")]
        rows = metrics_rows(d)
        assert [s for s, _ in logged] == [int(r["step"]) for r in rows]
        assert [v for _, v in logged] == pytest.approx([float(r["lagrange_multiplier"]) for r in rows])


# fork: each agent's own env (AgentEnvs), whose state is every agent's env's.
@pytest.mark.parametrize(
    "algo, env", [("ppo_lag", "reach1d"), ("cup", "reach1d"), ("ppo_lag", "fork"), ("cpo", "reach1d")]
)
def test_population_resumes_after_a_kill(tmp_path, algo, env):
    raw = torch_tiny(algo={"name": algo}) if env == "reach1d" else _fork(algo)
    if algo != "ppo_lag":
        raw["algo"] = _tiny_algo(algo)
    raw["population"] = {"seeds": 2, "grid": {"algo": {"cost_limit": [0.2]}}}
    whole = _population(tmp_path, raw, "whole")

    def kill_at_3(line: str) -> None:  # after iteration 3's rows, before any checkpoint of it
        if line.startswith("iteration 3/"):
            raise KeyboardInterrupt

    killed = tmp_path / "killed"
    with pytest.raises(KeyboardInterrupt):
        train(population(raw), killed, echo=kill_at_3)
    assert not list(killed.glob("agents/*/eval.json"))
    torch.load(killed / "checkpoint.pt", weights_only=True)  # plain tensors, numbers and strings
    train(resume_population(killed), killed, echo=lambda s: None)
    for a, b in zip(sorted((whole / "agents").iterdir()), sorted((killed / "agents").iterdir())):
        assert metrics_rows(a) == metrics_rows(b)  # same process, same code: bit for bit
        assert eval_result(a) == eval_result(b)


def test_a_population_resume_changes_what_a_run_s_resume_may(tmp_path):
    """One resume rule for runs and populations (run/resume.py's RESUMABLE): total_steps extends a
    finished population, which then equals one trained that long; algo.lr or the population's grid
    is refused in one line, before anything is written."""
    raw = torch_tiny(algo={"name": "ppo_lag"})
    raw["population"] = {"seeds": 2}
    short = _population(tmp_path, {**raw, "total_steps": 2 * 64}, "short")
    long = _population(tmp_path, raw, "long")
    before = {p: p.read_bytes() for p in short.rglob("*") if p.is_file()}
    for key, value, refused in [
        ("algo.lr", 1e-3, "algo.lr cannot change when resuming"),
        ("population.seeds", 3, "population cannot change when resuming"),
    ]:
        asked = copy.deepcopy(raw)
        node = asked
        for part in key.split(".")[:-1]:
            node = node[part]
        node[key.split(".")[-1]] = value
        with pytest.raises(ConfigError) as err:
            train(resume_population(short, asked, [key, "total_steps"]), short, echo=lambda s: None)
        assert str(err.value).startswith(refused) and "\n" not in str(err.value)
    assert {p: p.read_bytes() for p in short.rglob("*") if p.is_file()} == before
    train(resume_population(short, raw, ["total_steps"]), short, echo=lambda s: None)
    for a, b in zip(sorted((long / "agents").iterdir()), sorted((short / "agents").iterdir())):
        assert len(metrics_rows(b)) == 4
        assert metrics_rows(a) == metrics_rows(b)


OLD_POPULATION = Path(__file__).parent / "fixtures" / "old_population" / "ppo_lag"


@pytest.mark.cpu_kernels
def test_a_population_of_the_stacked_layout_resumes(tmp_path):
    """A population killed at iteration 3 by commit 8dc7aaa (the stacked checkpoint layout: every
    agent's networks and Adam moments as rows of one tensor; ``test_population_resumes_after_a_kill``'s
    ppo_lag run, recorded with the kill at iteration 3) resumes from its iteration-2 checkpoint into
    the numbers of an uninterrupted population, and its checkpoint is then one entry per agent."""
    old = torch.load(OLD_POPULATION / "population.pt", weights_only=True)
    assert "update" in old and "agents" not in old and old["iteration"] == 2  # else this proves nothing
    killed = tmp_path / "killed"
    shutil.copytree(OLD_POPULATION, killed)
    train(resume_population(killed), killed, echo=lambda s: None)
    # the recorded population ran with the defaults of its day, which its config does not name
    raw = saved_config_defaults(yaml.safe_load((OLD_POPULATION / "population.yaml").read_text()))
    whole = _population(tmp_path, raw, "whole")
    for a, b in zip(sorted((whole / "agents").iterdir()), sorted((killed / "agents").iterdir())):
        assert_same_outputs(metrics_rows(b), metrics_rows(a), b.name)
        assert_same_outputs(eval_result(b), eval_result(a), b.name)
    new = torch.load(killed / "checkpoint.pt", weights_only=True)
    assert "update" not in new and [e["algo_state"]["iteration"] for e in new["members"]] == [4, 4]


@pytest.mark.parametrize(
    "population, message",
    [
        (
            {"grid": {"algo": {"cost_limit": [0.2, -1.0]}}},
            "population.grid.algo.cost_limit: agent 1 (algo.cost_limit=-1.0,seed=0): algo.cost_limit must be",
        ),
        ({"grid": {"algo": {"gamma": [0.9, 0.99]}}}, "population.grid.algo.gamma must be one of the per-agent fields"),
        ({"grid": {"algo": {"lr": 0.1}}}, "population.grid.algo.lr must be a non-empty list"),
        ({"seeds": 0}, "population.seeds must be a positive integer"),
    ],
)
def test_bad_population_config_is_one_line(population, message):
    raw = torch_tiny()
    raw["population"] = population
    with pytest.raises(ConfigError) as err:
        agent_configs(raw)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


# What the batched program does not cover, one case each: such a population's agents train one
# after another through the single-run path (run.trainer.train).
UNBATCHED = [
    ({"algo": {"name": "sac_lag"}}, "algo=sac_lag is not batched"),
    ({"policy": {"name": "gru"}}, "policy=gru is not batched"),
    ({"env": {"backend": "gym", "stagger": False}}, "env=reach1d (backend gym) is not batched"),
    ({"normalize": {"obs": True}}, "normalize is not batched"),
    ({"policy": {"include_prev_action": True}}, "policy=mlp with include_prev_* is not batched"),
    ({"env": {"name": "skills", "num_envs": 2}}, "the action head HybridHead is not batched"),
]


def _unbatched(change: dict) -> dict:
    raw = torch_tiny()
    for k, v in change.items():
        raw[k] = {**raw.get(k, {}), **v} if isinstance(v, dict) else v
    if raw["algo"]["name"] != "ppo_lag":  # another algorithm's tiny options, not ppo_lag's
        raw["algo"] = {"name": raw["algo"]["name"], **component("algo", raw["algo"]["name"]).options.tiny}
    if raw["env"].get("name") == "skills":
        raw["env"] = {"name": "skills", "num_envs": 2}
        raw["algo"] = {"name": "ppo"}
    raw["population"] = {"seeds": 2}
    return raw


@pytest.mark.parametrize("change, why", UNBATCHED)
def test_an_unbatched_population_trains_each_agent_as_its_single_run(tmp_path, change, why):
    """Each agent equals ``train()`` on its own config.yaml exactly (the same code, one after
    another in one process: the second agent's numbers must not depend on the first's)."""
    said = []
    summary = train(population(_unbatched(change)), tmp_path / "pop", echo=said.append)
    assert said[0].startswith(f"population: {why}") and "2 agents train one after another" in said[0]
    dirs = sorted((tmp_path / "pop" / "agents").iterdir())
    assert [r["dir"] for r in summary["runs"]] == [f"agents/{d.name}" for d in dirs] and len(dirs) == 2
    for i in (1, 0):  # the second agent first: alone in its process state
        cfg = load_config(yaml.safe_load((dirs[i] / "config.yaml").read_text()))
        assert cfg.seed == i
        train(cfg, tmp_path / f"single{i}", echo=lambda s: None)
        assert metrics_rows(dirs[i]) == metrics_rows(tmp_path / f"single{i}")
        assert eval_result(dirs[i]) == eval_result(tmp_path / f"single{i}")


def test_an_unbatched_population_resumes_after_a_kill(tmp_path):
    """Killed in its second agent's training: the resume continues that agent from its checkpoint
    (the first, finished, is evaluated again) and ends with the numbers of the whole population."""
    raw = _unbatched({"policy": {"name": "gru"}})
    raw["checkpoint_every"] = 2
    whole = _population(tmp_path, raw, "whole")

    def kill_at_3(line: str) -> None:  # the second agent's third iteration, after its checkpoint of 2
        if line.startswith("agent 2/"):
            kill_at_3.second = True
        if getattr(kill_at_3, "second", False) and line.lstrip().startswith("iter    3"):
            raise KeyboardInterrupt

    killed = tmp_path / "killed"
    with pytest.raises(KeyboardInterrupt):
        train(population(raw), killed, echo=kill_at_3)
    assert (killed / "agents/000_seed=0/eval.json").is_file() and not (killed / "agents/001_seed=1/eval.json").exists()
    train(resume_population(killed), killed, echo=lambda s: None)
    for a, b in zip(sorted((whole / "agents").iterdir()), sorted((killed / "agents").iterdir())):
        assert metrics_rows(a) == metrics_rows(b)
        assert eval_result(a) == eval_result(b)


def test_train_cli_trains_an_unbatched_population(tmp_path):
    proc = run_script(
        "train.py",
        "policy=gru",
        "env=reach1d_torch",
        "population.seeds=2",
        "total_steps=128",
        "env.num_envs=2",
        "rollout_steps=16",
        "algo.num_minibatches=2",
        "eval_episodes=2",
        f"hydra.run.dir={tmp_path}/r",
    )
    assert proc.returncode == 0, proc.stderr
    assert "population: policy=gru is not batched" in proc.stdout
    assert len(list((tmp_path / "r" / "agents").glob("*/eval.json"))) == 2


def test_the_exercise_grid_as_populations():
    """experiments/studies/penalty_vs_constraint.py --population: each algorithm of a sweep is one
    population whose agents are the sweep's jobs."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from cmdp_rl.config.run_config import CONFIG_DIR
    from lab.studies.population_sweep import sweep_parts

    parts = sweep_parts("constraint_sweep")
    assert [(p.name, p.batched) for p in parts] == [("ppo_lag", True), ("pid_lag", True), ("cpo", True)]
    (penalty,) = sweep_parts("penalty_sweep")
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        raw = OmegaConf.to_container(
            compose("config", overrides=penalty.overrides("penalty_sweep", ["env.backend=torch"])), resolve=True
        )
        cpo = compose("config", overrides=parts[2].overrides("constraint_sweep", ["env.backend=torch"]))
    cpo_cfgs = agent_configs(OmegaConf.to_container(cpo, resolve=True))[1]
    assert len(cpo_cfgs) == 30 and {c.algo.name for c in cpo_cfgs} == {"cpo"}
    assert unbatched(cpo_cfgs[0]) is None  # batched: its envs and acting at once, each agent's own update
    overrides, cfgs = agent_configs(raw)
    assert len(cfgs) == 42 and {c.algo.name for c in cfgs} == {"penalty"}
    assert sorted({(c.algo.penalty, str(c.env.start)) for c in cfgs}) == sorted(
        (p, s) for p in (0.0, 0.5, 1.0, 1.25, 1.5, 2.0, 3.0) for s in ("0.1", "[0.0, 1.0]")
    )
    assert [c.seed for c in cfgs[:3]] == [0, 1, 2] and cfgs[0].algo.update_epochs == 10


@pytest.mark.cpu_kernels
def test_fused_pass_gradients_equal_autograd_path():
    """population/stacked.py's hand-written backward (FusedTanhMLP) gives the per-layer autograd path's outputs and
    gradients bit for bit (same kernels, same order), on sizes past the sigmoid-tanh threshold. The loss is shaped as
    training's (squared errors, a log-likelihood), whose gradients are dense: a loss linear in an output (``c *
    cost.sum()``) hands autograd's path a stride-0 gradient, and on an Intel Xeon with AVX-512 (Sapphire Rapids) torch
    multiplies that in its own bmm loop where the fused path's dense one goes to MKL, so the last layer's weight
    gradient then differs in the last bits (measured 2026-12-08: 186 of 8,834 entries, at most 2.6e-4)."""
    import torch

    from cmdp_rl.envs import make_env
    from cmdp_rl.policies import make_agent
    from cmdp_rl.population.stacked import PopulationAgent
    from cmdp_rl.rollout.normalization import make_normalizers
    from cmdp_rl.run.rng import seed_everything

    raw = torch_tiny(algo={"name": "ppo_lag"})
    raw["population"] = {"seeds": 3, "grid": {}}
    _, cfgs = agent_configs(raw)
    agents = []
    for c in cfgs:
        seed_everything(c.seed)
        probe = make_env(c.env, device="cpu")
        agents.append(make_agent(c.policy, probe, make_normalizers(c, probe)))
    pop = PopulationAgent(agents, [torch.Generator() for _ in agents], torch.device("cpu"))
    assert pop.layout is not None
    gen = torch.Generator().manual_seed(0)
    obs = torch.randn(3, 4096, agents[0].actor.head.net[0].weight.shape[1], generator=gen)
    action = torch.randn(3, 4096, 1, generator=gen)
    results = []
    for fused_layout in (pop.layout, None):
        pop.layout = fused_layout
        pop.actor.flat.grad = pop.critics.flat.grad = None
        dist, value, cost = pop.training_pass(obs)
        (dist.log_prob(action).sum() + value.pow(2).sum() + (cost - 3).pow(2).sum()).backward()
        results.append([dist.mean.detach(), value.detach(), cost.detach(), pop.actor.flat.grad, pop.critics.flat.grad])
    for fused, reference in zip(*results):
        assert torch.equal(fused, reference)


def test_the_population_benchmark_runs_end_to_end(tmp_path):
    """A smoke run of experiments/speed/population_benchmark.py (its figures are not checked): the
    population, the same agents one after another, and a scan whose sizes repeat the first's."""
    from lab.bench.population_benchmark import main

    out = tmp_path / "bench.json"
    assert (
        main(["--agents", "2", "--envs", "2", "--iterations", "1", "--scan", "2,1", "--skip-layers", "--out", str(out)])
        == 0
    )
    report = json.loads(out.read_text())
    assert report["final_policy"] == "last" and [r["agents"] for r in report["scan"]] == [2, 1]
    assert report["together"]["steps_summed"] == report["one_after_another"]["steps_summed"] > 0


def test_a_finished_population_s_directory_is_refused_as_finished(tmp_path):
    raw = torch_tiny()
    raw["population"] = {"seeds": 2}
    pop = _population(tmp_path, raw)
    with pytest.raises(RunDirTaken, match="already holds a finished run"):
        train(population(raw), pop, echo=lambda s: None)
