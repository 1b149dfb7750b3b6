"""The ``deploy:`` node replaced six flat run options (``final_policy``, ``average_last``, ``mixture_size``,
``mixture_weights``, ``mixture_episodes``, ``mixture_margin``): a config saved with them maps to the node with
the same values (run/migrations.py), so a run directory written before the node evaluates, loads and
resumes exactly as one written with it."""

import shutil

import numpy as np
import pytest
import torch
import yaml
from helpers.runs import eval_result, metrics_rows, tiny

import cmdp_rl
from cmdp_rl import load_config, train
from cmdp_rl.cli import evaluate as evaluate_cli  # the command's main, in-process
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.population import population
from cmdp_rl.population.resume import resume_population
from cmdp_rl.report.plot import group_runs
from cmdp_rl.report.sweeps import load_run
from cmdp_rl.run.checkpoint import load_checkpoint, save_checkpoint
from cmdp_rl.run.migrations import saved_config_defaults

# Each flat option, by its name in the node.
FLAT = {
    "policy": "final_policy",
    "window": "average_last",
    "snapshots": "mixture_size",
    "weights": "mixture_weights",
    "episodes": "mixture_episodes",
    "margin": "mixture_margin",
}


def flat(config: dict) -> dict:
    """``config`` as the code before the node saved it: the node's fields as top-level options."""
    out = {k: v for k, v in config.items() if k != "deploy"}
    out.update({FLAT[k]: v for k, v in config["deploy"].items()})
    return out


def write_flat(run) -> None:
    """Rewrite a run directory's config.yaml and its checkpoint's config as they were written before the node."""
    config = yaml.safe_load((run / "config.yaml").read_text())
    (run / "config.yaml").write_text(yaml.safe_dump(flat(config), sort_keys=False))
    state = load_checkpoint(run / "checkpoint.pt")
    members = [{**m, "config": flat(m["config"])} for m in state["members"]]
    save_checkpoint(run / "checkpoint.pt", {**state, "members": members})


def test_flat_options_map_to_the_node_with_their_values():
    saved = {
        "algo": {"name": "ppo_lag"},
        "seed": 3,
        "final_policy": "mixture",
        "average_last": 0.3,
        "mixture_size": 4,
        "mixture_weights": "uniform",
        "mixture_episodes": 7,
        "mixture_margin": 1.5,
    }
    got = saved_config_defaults(saved)
    want = {"policy": "mixture", "window": 0.3, "snapshots": 4, "weights": "uniform", "episodes": 7, "margin": 1.5}
    assert got["deploy"] == want and not set(FLAT.values()) & set(got) and got["seed"] == 3
    assert saved_config_defaults(got) == got  # a config of the node is as it is
    cfg = load_config(got)
    assert (cfg.deploy.policy, cfg.deploy.window, cfg.deploy.snapshots, cfg.deploy.margin) == ("mixture", 0.3, 4, 1.5)
    # before mixture_weights existed: the deployment defaults of its day, under the node, where it names none
    older = saved_config_defaults({"algo": {"name": "ppo_lag"}, "final_policy": "average"})
    assert older["deploy"] == {"policy": "average", "window": 0.25, "snapshots": 8, "weights": "uniform"}
    assert older["algo"]["multiplier"]["scale"] == "none"  # the multiplier's default of its day, in its node


def test_a_flat_option_given_to_a_new_run_is_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"^config: unknown option\(s\) \['final_policy'\]"):
        load_config(tiny(final_policy="last"))


def test_a_run_saved_with_the_flat_options_evaluates_loads_and_resumes_unchanged(tmp_path, quiet):
    new, old = tmp_path / "new", tmp_path / "old"
    train(load_config(tiny(total_steps=4 * 32)), new, echo=quiet)  # deploys a valued mixture (auto)
    shutil.copytree(new, old)
    write_flat(old)
    assert "final_policy" in yaml.safe_load((old / "config.yaml").read_text())  # else this proves nothing
    assert "final_policy" in load_checkpoint(old / "checkpoint.pt")["members"][0]["config"]

    episodes = ("episode_return", "episode_cost", "episode_length")
    for run in (new, old):  # evaluate.py repeats the run's evaluation of the deployed mixture
        assert evaluate_cli.main([f"run={run}", f"output={run / 'again.json'}"]) == 0
        again = yaml.safe_load((run / "again.json").read_text())
        assert again["final_policy"] == "mixture"
        assert {k: again[k] for k in episodes} == {k: eval_result(new)[k] for k in episodes}

    obs = np.array([[0.1, 0.9], [0.4, 0.2], [0.45, 0.7]], dtype=np.float32)
    actions = []
    for run in (new, old):  # the same deployed mixture: the same member drawn from the same generator
        torch.manual_seed(0)
        actions.append(cmdp_rl.load(run).predict(obs, deterministic=True)[0])
    np.testing.assert_array_equal(*actions)

    for run in (new, old):  # to TINY's 7 iterations
        train(load_config(tiny(resume=str(run))), echo=quiet)
    assert metrics_rows(old) == metrics_rows(new)
    assert eval_result(old) == eval_result(new)


def test_a_population_saved_with_the_flat_options_resumes_unchanged(tmp_path):
    raw = tiny(env={"backend": "torch", "num_envs": 4, "stagger": True}, total_steps=4 * 64)
    raw["population"] = {"seeds": 2}
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    train(population(raw), whole, echo=lambda s: None)

    def kill_at_3(line: str) -> None:  # after iteration 3's rows, past the checkpoint of iteration 2
        if line.startswith("iteration 3/"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(population(raw), killed, echo=kill_at_3)
    saved = yaml.safe_load((killed / "population.yaml").read_text())
    (killed / "population.yaml").write_text(yaml.safe_dump(flat(saved), sort_keys=False))
    state = load_checkpoint(killed / "checkpoint.pt")
    members = [{**m, "config": flat(m["config"])} for m in state["members"]]
    save_checkpoint(killed / "checkpoint.pt", {**state, "members": members})
    train(resume_population(killed), killed, echo=lambda s: None)
    for a, b in zip(sorted((whole / "agents").iterdir()), sorted((killed / "agents").iterdir())):
        assert metrics_rows(b) == metrics_rows(a)
        assert eval_result(b) == eval_result(a)
        assert eval_result(b)["final_policy"] == "mixture"  # the valued mixture, with TINY's 8 episodes each


def test_plot_and_compare_read_either_layout_as_the_node(tmp_path, quiet):
    a, b = tmp_path / "a", tmp_path / "b"
    train(load_config(tiny(total_steps=2 * 32)), a, echo=quiet)
    shutil.copytree(a, b)
    config = flat(yaml.safe_load((b / "config.yaml").read_text()))
    config.update(seed=1, final_policy="average")  # another seed, saved before the node, deploying otherwise
    (b / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    (curve,) = group_runs([a, b])
    assert curve.seeds == 2 and curve.label == "ppo_lag, 2 seeds"  # curves group across what runs deploy
    # compare (run/sweeps.py) groups by the node: `--by deploy.policy` tells these two apart
    assert [load_run(r).config["deploy"]["policy"] for r in (a, b)] == ["mixture", "average"]
    assert "final_policy" not in load_run(b).config
