"""The probe experiment's pieces: the probe rate of a policy, and the report from finished runs."""

import csv
import json
from pathlib import Path

import pytest
import torch
import yaml

from cmdp_rl import load_config, make_agent, make_env  # noqa: E402
from cmdp_rl.run.checkpoint import save_checkpoint  # noqa: E402
from lab.studies import probe_belief  # noqa: E402


@pytest.mark.parametrize("policy", ["mlp", "lstm"])
@pytest.mark.parametrize("probe_loc", [0.9, -0.9])
def test_probe_rate_counts_the_policys_probes(tmp_path, policy, probe_loc):
    """A policy whose probe dimension has mean +0.9 (std 0.06) probes on (almost) every step;
    with mean -0.9, on none."""
    cfg = load_config(
        {
            "policy": {"name": policy, "init_log_std": -3.0},
            "seed": 0,
            "rollout_steps": 64,
            "env": {"backend": "torch", "num_envs": 16, "probe": True, "max_steps": 10},
        }
    )
    ac = make_agent(cfg.policy, make_env(cfg.env))
    head = ac.actor.head  # the Gaussian head, whatever the body
    with torch.no_grad():
        head.center[1] = probe_loc  # the probe dimension's mean, whatever the network outputs
    save_checkpoint(tmp_path / "checkpoint.pt", {"policy": policy, "algo_state": {"networks": ac.state_dict()}})
    stats = probe_belief.probe_stats(cfg, tmp_path, steps=20)
    expected = 1.0 if probe_loc > 0 else 0.0
    assert stats["probe_rate"] == pytest.approx(expected, abs=1e-3) and stats["steps"] == 320
    assert stats["probe_rate_early"] == pytest.approx(expected, abs=1e-3)
    no_probe = load_config({"env": {"probe": False}})
    assert probe_belief.probe_stats(no_probe, tmp_path, steps=20)["probe_rate"] is None


# (policy, probe, seed) -> eval return, eval cost, probe rate, training steps/s
RUNS = {
    ("mlp", False, 0): (1.0, 1.2, None, 30000.0),
    ("mlp", False, 1): (0.8, 1.4, None, 20000.0),
    ("lstm", True, 0): (1.5, 1.0, 0.2, 3000.0),
    ("lstm", True, 1): (1.3, 1.0, 0.4, 5000.0),
}


def _fake_sweep(root: Path) -> None:
    for (policy, probe, seed), (ret, cost, rate, sps) in RUNS.items():
        d = root / f"{policy}_probe{probe}_s{seed}"
        d.mkdir(parents=True)
        (d / "config.yaml").write_text(
            yaml.safe_dump({"policy": {"name": policy}, "env": {"probe": probe}, "seed": seed})
        )
        (d / "eval.json").write_text(
            json.dumps(
                {
                    "episode_return": ret,
                    "episode_cost": cost,
                    "goal_reached": 0.5,
                    "episode_length": 10.0,
                    "cost_limit": 1.0,
                    "steps": 8192,
                }
            )
        )
        (d / "probe.json").write_text(
            json.dumps({"probe_rate": rate, "probe_rate_early": rate, "probe_rate_later": rate})
        )
        with open(d / "metrics.csv", "w", newline="") as f:
            w = csv.DictWriter(f, ["step", "sps"])
            w.writeheader()
            w.writerows([{"step": 4096, "sps": 1.0}, {"step": 8192, "sps": sps}])  # the first is warm-up


def test_report_groups_by_policy_and_probe(tmp_path):
    _fake_sweep(tmp_path)
    probe_belief.gather(tmp_path)
    rows = list(csv.DictReader(open(tmp_path / "table.csv")))
    assert [(r["policy"], r["probe"]) for r in rows] == [("mlp", "False"), ("lstm", "True")]
    mlp, lstm = rows
    assert float(mlp["episode_return"]) == pytest.approx(0.9) and float(mlp["episode_cost_std"]) == pytest.approx(0.1)
    assert mlp["probe_rate"] == "" and float(lstm["probe_rate"]) == pytest.approx(0.3)
    assert float(mlp["train_sps"]) == 25000.0
    text = (tmp_path / "table.md").read_text()
    assert "| lstm | yes | 2 | 8,192 | 1.400 ± 0.100 | 1.000 ± 0.000 |" in text and "| mlp | no |" in text
    assert (tmp_path / "cost_vs_return.png").stat().st_size > 10_000
