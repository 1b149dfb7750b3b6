"""evaluate.py: loads a run, repeats its evaluation, draws Reach1D episodes, refuses bad input."""

import json

import pytest
import torch
from helpers.runs import eval_result, run_script, tiny

from cmdp_rl import keys, load_config, train
from cmdp_rl.cli import evaluate as evaluate_cli
from cmdp_rl.envs.reach1d.task import Reach1DConfig
from cmdp_rl.report.reach1d_episodes import plot_reach1d, record_reach1d
from cmdp_rl.run.checkpoint import load_checkpoint, save_checkpoint


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    train(load_config(tiny(total_steps=64)), out, echo=lambda s: None)
    return out


def test_default_evaluation_repeats_the_runs_eval_json(run, tmp_path, capsys):
    out = tmp_path / "e.json"
    assert evaluate_cli.main([f"run={run}", f"output={out}"]) == 0
    got, want = json.loads(out.read_text()), eval_result(run)
    # eval.json adds training-time figures (cost rate over training, normalized scores); the
    # evaluation's own numbers must be the same
    same = {"episodes", "deterministic", "goal_reached", "cost_limit"} | {
        f"episode_{m}{s}" for m in ("return", "cost", "length") for s in ("", "_std", "_min", "_max")
    }
    assert same <= got.keys() and {k: got[k] for k in same} == {k: want[k] for k in same}
    text = capsys.readouterr().out
    assert "episode_return" in text and "episode_cost" in text and "±" in text and "[min" in text


def test_stochastic_evaluation_is_seeded(run, tmp_path):
    a, b, c = (tmp_path / f"{n}.json" for n in "abc")
    for path, seed in ((a, 7), (b, 7), (c, 8)):
        args = [f"run={run}", "deterministic=false", "episodes=6", f"seed={seed}", f"output={path}"]
        assert evaluate_cli.main(args) == 0
    ra, rb, rc = (json.loads(p.read_text()) for p in (a, b, c))
    assert ra == rb and ra["episodes"] == 6 and not ra["deterministic"]
    assert ra["episode_return"] != rc["episode_return"]


def test_plot_writes_a_png(run, tmp_path):
    png = tmp_path / "eps.png"
    assert evaluate_cli.main([f"run={run}", f"plot={png}", "plot_episodes=2", "episodes=2"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_replay_records_the_true_position_and_collisions(tmp_path):
    class Forward:
        """An agent that always pushes forward by 0.1 (what replay needs of one: act, in_keys,
        initial_state)."""

        in_keys = [keys.OBS]

        def initial_state(self, num_envs, device="cpu"):
            return {}

        def act(self, d, deterministic=False):
            return {keys.ACTION: torch.full((d[keys.OBS].shape[0], 1), 0.1)}

    actor = Forward()
    cfg = Reach1DConfig(max_steps=8)
    (ep,) = record_reach1d(actor, cfg, 1, seed=0)
    # float32 0.1 steps from 0.1: 0.2, 0.3, 0.4, 0.5000000x would cross, so blocked at ~0.4 from step 4
    assert len(ep.true_x) == 9 and ep.true_x[0] == 0.1
    assert ep.cost == [0, 0, 0, 1, 1, 1, 1, 1] and max(ep.true_x) < 0.5
    assert ep.true_x[3:] == [ep.true_x[3]] * 6 and not ep.terminated
    assert all(abs(r - x) < 0.2 for r, x in zip(ep.reading, ep.true_x))  # noisy readings of x
    png = plot_reach1d([ep, ep], cfg, tmp_path / "p.png")
    assert png.stat().st_size > 10_000


def doctored(src, dst, **changes):
    state = load_checkpoint(src)
    state.update(changes)
    state.pop("format")
    save_checkpoint(dst, state)


BAD_OPTIONS = [
    (["episodes=0"], "episodes must be a positive integer"),
    (["plot_episodes=0"], "plot_episodes must be a positive integer"),
    (["plot=out.jpg"], "plot must be a path ending in .png"),
    (["bogus=1"], "unknown option(s) ['bogus']"),
    (["deterministic=maybe"], "evaluate.deterministic"),
]


@pytest.mark.parametrize("args,message", BAD_OPTIONS, ids=[m.split()[0] for _, m in BAD_OPTIONS])
def test_bad_options_are_named(run, capsys, args, message):
    assert evaluate_cli.main([f"run={run}", *args]) == 2
    assert message in capsys.readouterr().err


def test_missing_corrupt_and_foreign_checkpoints_are_refused(run, tmp_path, capsys):
    def refused(args, message):
        assert evaluate_cli.main(args) == 2
        err = capsys.readouterr().err
        assert message in err, err

    refused([str(run)], "options are key=value")
    refused([], "run must be a run directory")
    refused([f"run={tmp_path / 'nowhere'}"], "no run directory at")
    (tmp_path / "empty").mkdir()
    refused([f"run={tmp_path / 'empty'}"], "no checkpoint.pt in")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes((run / "checkpoint.pt").read_bytes()[:5000])  # cut short, as by a full disk
    refused([f"run={run}", f"checkpoint={corrupt}"], "is corrupt or not a cmdp_rl checkpoint")
    other_algo = tmp_path / "ppo.pt"
    doctored(run / "checkpoint.pt", other_algo, algo="ppo")
    refused([f"run={run}", f"checkpoint={other_algo}"], "written by algo='ppo', but this run uses algo='ppo_lag'")
    other_policy = tmp_path / "lstm.pt"
    doctored(run / "checkpoint.pt", other_policy, policy="lstm")
    refused([f"run={run}", f"checkpoint={other_policy}"], "written by policy='lstm', but this run uses policy='mlp'")
    # a checkpoint whose networks do not fit the run's config (another network size)
    wide = tmp_path / "wide"
    train(load_config(tiny(total_steps=32, policy={"hidden_sizes": [8]})), wide, echo=lambda s: None)
    refused([f"run={run}", f"checkpoint={wide / 'checkpoint.pt'}"], "does not fit the config of")


def test_cli_in_a_subprocess(run):
    """The other tests call evaluate.py's main() in-process; this one runs the script itself."""
    proc = run_script("evaluate.py", f"run={run}", "episodes=2")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "2 episodes, deterministic policy" in proc.stdout


def test_a_mujoco_run_with_normalization_evaluates_as_it_did_in_training(tmp_path):
    pytest.importorskip("mujoco")
    cfg = {
        "env": {"name": "velocity", "task": "Hopper", "num_envs": 3, "max_steps": 20},
        "algo": {"name": "ppo", "update_epochs": 1, "num_minibatches": 2},
        "normalize": {"obs": True, "reward": True},
        "rollout_steps": 16,
        "total_steps": 96,
        "eval_episodes": 2,
    }
    train(load_config(cfg), tmp_path, echo=lambda s: None)  # evaluates on 2 envs, trained on 3
    out = tmp_path / "e.json"
    assert evaluate_cli.main([f"run={tmp_path}", f"output={out}"]) == 0
    got, want = json.loads(out.read_text()), eval_result(tmp_path)
    assert got["episode_return"] == want["episode_return"] and got["episode_cost"] == want["episode_cost"]


def test_eval_json_has_the_interval_estimates(run, capsys):
    ev = eval_result(run)
    n, d = ev["episodes"], ev["cost_limit"]
    assert ev["intervals"]["level"] == 0.95 and ev["intervals"]["violation"] == f"episode cost > {d:g}"
    for name in ("episode_return", "episode_cost"):
        lo, hi = ev[f"{name}_ci95"]
        assert ev[f"{name}_min"] <= lo <= ev[name] <= hi <= ev[f"{name}_max"]
    assert ev["episode_cost_ci95"][0] <= ev["episode_cost_ucb95"] <= ev["episode_cost_ci95"][1]
    assert 0 <= ev["violations"] <= n and ev["violation_rate"] == ev["violations"] / n
    lo, hi = ev["violation_rate_ci95"]
    assert lo <= ev["violation_rate"] <= ev["violation_rate_ucb95"] <= hi
    assert evaluate_cli.main([f"run={run}"]) == 0
    text = capsys.readouterr().out
    assert f"violations {ev['violations']}/{n} episodes (cost > {d:g})" in text and "95% CI" in text
