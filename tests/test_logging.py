"""Logging: the same metric names for every algorithm, in CSV and TensorBoard; plots of runs."""

import csv

import numpy as np
import pytest
from helpers.runs import tiny

from cmdp_rl import load_config, train
from cmdp_rl.algos.ppo import PPO
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.report.metrics import MetricsLogger, columns
from cmdp_rl.report.plot import aggregate, group_runs, smooth
from cmdp_rl.report.plot import main as plot_main
from cmdp_rl.run.resume import resume_config

pytest.importorskip("tensorboard")
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator  # noqa: E402


def scalars(run_dir):
    acc = EventAccumulator(str(run_dir / "tb"))
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


@pytest.mark.parametrize("algo", ["ppo", "penalty", "ppo_lag"])
def test_every_algorithm_logs_the_same_names_to_csv_and_tensorboard(tmp_path, quiet, algo):
    cfg = tiny(algo={"name": algo}, logger={"name": "tensorboard"}, total_steps=3 * 32)
    if algo != "ppo_lag":
        cfg["algo"].pop("multiplier")
    train(load_config(cfg), tmp_path, echo=quiet)
    with open(tmp_path / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    cols = columns(PPO.stats)  # the PPO family declares the same statistics
    assert list(rows[0].keys()) == cols and len(rows) == 3
    tb = scalars(tmp_path)
    # every column with a number in it (the normalized scores stay blank without a reference)
    numeric = {k for k in cols[2:] if any(r[k] not in ("", "nan") for r in rows)}
    assert {"episode_cost", "lagrange_multiplier", "cost_rate", "loss_pi"} <= numeric
    assert set(tb) == numeric
    assert [s for s, _ in tb["lagrange_multiplier"]] == [int(r["step"]) for r in rows]
    assert [v for _, v in tb["lagrange_multiplier"]] == pytest.approx([float(r["lagrange_multiplier"]) for r in rows])


def test_resumed_tensorboard_log_has_no_duplicate_steps(tmp_path, monkeypatch, quiet):
    whole, broken = tmp_path / "whole", tmp_path / "broken"
    cfg = tiny(logger={"name": "tensorboard"})
    train(load_config(cfg), whole, echo=quiet)
    original = MetricsLogger.log

    def crash_at_5(self, row, force_echo=False, **kwargs):
        original(self, row, force_echo, **kwargs)
        if row["iteration"] == 5:
            self.sync()  # its events are on disk, as a killed run's may be
            raise KeyboardInterrupt

    monkeypatch.setattr(MetricsLogger, "log", crash_at_5)
    with pytest.raises(KeyboardInterrupt):
        train(load_config(cfg), broken, echo=quiet)
    monkeypatch.undo()
    train(load_config({**cfg, "resume": str(broken)}), echo=quiet)
    a, b = scalars(whole), scalars(broken)
    for tag in ("episode_cost", "lagrange_multiplier", "loss_pi"):
        assert a[tag] == b[tag], tag  # steps once each, in order, same values


def test_resume_may_switch_the_logger(tmp_path, quiet):
    train(load_config(tiny(total_steps=64)), tmp_path, echo=quiet)
    cfg = resume_config(tmp_path, {**tiny(), "logger": {"name": "tensorboard"}}, ["logger"])
    assert cfg.logger.name == "tensorboard" and cfg.resume == str(tmp_path)


def test_missing_tensorboard_is_a_clear_config_error(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "tensorboard" else real(name, *a))
    with pytest.raises(ConfigError, match=r"^logger.name: logger=tensorboard needs the tensorboard package: pip"):
        load_config({"logger": {"name": "tensorboard"}})
    assert load_config({"logger": {"name": "csv"}}).logger.name == "csv"


def test_smooth_and_aggregate_skip_missing_values():
    x = np.array([1.0, np.nan, 3.0, 5.0])
    assert np.allclose(smooth(x, 2), [1.0, 1.0, 3.0, 4.0])
    runs = [
        {
            "step": np.array([10.0, 20.0, 30.0]),
            "episode_return": np.array([1.0, np.nan, 3.0]),
            "episode_cost": np.array([0.0, 2.0, 4.0]),
            "lagrange_multiplier": np.zeros(3),
        },
        {
            "step": np.array([10.0, 20.0]),
            "episode_return": np.array([3.0, 5.0]),
            "episode_cost": np.array([2.0, 2.0]),
            "lagrange_multiplier": np.ones(2),
        },
    ]
    step, mean, std = aggregate(runs)
    assert step.tolist() == [10.0, 20.0]  # the iterations both runs reached
    assert mean["episode_return"].tolist() == [2.0, 5.0] and std["episode_return"].tolist() == [1.0, 0.0]
    assert mean["episode_cost"].tolist() == [1.0, 2.0] and mean["lagrange_multiplier"].tolist() == [0.5, 0.5]


def test_plot_groups_seeds_and_writes_a_png(tmp_path, quiet, capsys):
    dirs = []
    for algo, seed in (("ppo", 0), ("ppo", 1), ("ppo_lag", 0)):
        cfg = tiny(algo={"name": algo}, seed=seed, total_steps=3 * 32)
        if algo == "ppo":
            cfg["algo"].pop("multiplier")
        train(load_config(cfg), tmp_path / f"{algo}_{seed}", echo=quiet)
        dirs.append(tmp_path / f"{algo}_{seed}")
    curves = {c.label: c for c in group_runs(dirs)}
    assert set(curves) == {"ppo, 2 seeds", "ppo_lag, 1 seed"}
    assert curves["ppo, 2 seeds"].cost_limit == 0.2 and len(curves["ppo, 2 seeds"].step) == 3
    out = tmp_path / "curves.png"
    assert plot_main([*map(str, dirs), "-o", str(out)]) == 0
    assert out.read_bytes()[:4] == b"\x89PNG" and out.stat().st_size > 20_000
    assert plot_main([str(tmp_path / "nothing"), "-o", str(out)]) == 2
    assert "no metrics.csv in" in capsys.readouterr().err
