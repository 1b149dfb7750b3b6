"""Same config and seed, same numbers; every run directory says what produced it."""

import json
import subprocess

import torch
import yaml
from helpers.runs import ROOT, eval_result, metrics_rows, tiny

import cmdp_rl
from cmdp_rl import load_config, train
from cmdp_rl.run.checkpoint import load_checkpoint


def test_same_config_and_seed_give_identical_metrics(tmp_path, quiet):
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        train(load_config(tiny(seed=seed)), tmp_path / name, echo=quiet)
    a, b, c = (metrics_rows(tmp_path / n) for n in "abc")
    assert len(a) == 7 and a == b  # every column but sps and time_s, as text: bit for bit
    assert eval_result(tmp_path / "a") == eval_result(tmp_path / "b")
    na, nb = (load_checkpoint(tmp_path / n / "checkpoint.pt")["members"][0]["algo_state"]["networks"] for n in "ab")
    assert all(torch.equal(na[k], nb[k]) for k in na)
    # the comparison can fail: another seed changes the numbers
    assert [r["episode_return"] for r in a] != [r["episode_return"] for r in c]


def test_run_directory_records_config_version_and_commit(tmp_path, quiet):
    cfg = load_config(tiny(total_steps=64))
    train(cfg, tmp_path, echo=quiet)
    assert load_config(yaml.safe_load((tmp_path / "config.yaml").read_text())) == cfg
    info = json.loads((tmp_path / "run_info.json").read_text())
    assert info["version"] == cmdp_rl.__version__ and info["resumes"] == []
    assert info["libraries"]["torch"] == torch.__version__
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    if head.returncode == 0:  # a git checkout: the commit is recorded, with its dirty flag
        assert info["git_commit"] == head.stdout.strip() and isinstance(info["git_dirty"], bool)
    train(load_config(tiny(total_steps=96, resume=str(tmp_path))), echo=quiet)
    info = json.loads((tmp_path / "run_info.json").read_text())
    assert [r["from_iteration"] for r in info["resumes"]] == [2]
    assert load_config(yaml.safe_load((tmp_path / "config.yaml").read_text())).total_steps == 96
