"""logger=wandb: an offline Weights & Biases run beside metrics.csv, read back from its files.

No network: the run is offline. wandb (0.31) writes an offline run as one transaction log,
``run-<id>.wandb``: LevelDB's log format (32 KiB blocks of records with a 7-byte header: checksum,
length, type) holding wandb's ``Record`` protobufs. :func:`records` reads it back, so the tests check
what wandb would upload: the config, one history row per metrics.csv row, and the summary.
"""

import csv
import importlib.util
import json
import struct
import time

import pytest
from helpers.runs import tiny

from cmdp_rl import load_config, train
from cmdp_rl.config.run_config import ConfigError, compose_config

pytest.importorskip("wandb")  # the test extra installs it (pip install -e '.[test]')
import wandb  # noqa: E402
from wandb.proto import wandb_internal_pb2 as pb  # noqa: E402


def records(path):
    """The protobuf records of a ``.wandb`` transaction log, in order."""
    data = path.read_bytes()
    ident, _magic, _version = struct.unpack("<4sHB", data[:7])
    assert ident == b":W&B"
    block, pos, parts, out = 32768, 7, b"", []
    while pos + 7 <= len(data):
        left = block - pos % block
        if left < 7:  # a block's tail too short for a header is padding
            pos += left
            continue
        _crc, length, kind = struct.unpack("<IHB", data[pos : pos + 7])
        if length == 0 and kind == 0:
            pos += left
            continue
        parts += data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        if kind in (1, 4):  # FULL, or LAST of a FIRST/MIDDLE/LAST chain
            rec = pb.Record()
            rec.ParseFromString(parts)
            out.append(rec)
            parts = b""
    return out


def offline_runs(run_dir):
    return sorted((run_dir / "wandb").glob("offline-run-*"))


def read_run(offline_dir):
    """(config, history rows, summary) of one offline run directory, values decoded from JSON."""
    # wandb's service process writes the log on its own schedule after run.finish() returns; shut it
    # down so every record is on disk (the next wandb.init starts a new one)
    wandb.teardown()
    (log,) = offline_dir.glob("run-*.wandb")
    config, history, summary = {}, [], {}
    for rec in records(log):
        kind = rec.WhichOneof("record_type")
        if kind in ("run", "config"):
            # wandb sends an update under a plain key or, depending on timing, a nested key path
            for u in rec.run.config.update if kind == "run" else rec.config.update:
                path = [u.key] if u.key else list(u.nested_key)
                node = config
                for part in path[:-1]:
                    node = node.setdefault(part, {})
                node[path[-1]] = json.loads(u.value_json)
        elif kind == "history":
            history.append({(i.key or i.nested_key[0]): json.loads(i.value_json) for i in rec.history.item})
        elif kind == "summary":
            summary.update({u.key: json.loads(u.value_json) for u in rec.summary.update if u.key})
    return config, history, summary


@pytest.fixture(autouse=True)
def wandb_home(tmp_path, monkeypatch):
    """wandb's own cache and settings go to the test's directory, not the user's home."""
    for var in ("WANDB_CACHE_DIR", "WANDB_CONFIG_DIR", "WANDB_DATA_DIR"):
        monkeypatch.setenv(var, str(tmp_path / "wandb_home"))
    monkeypatch.delenv("WANDB_MODE", raising=False)


def csv_rows(run_dir):
    with open(run_dir / "metrics.csv") as f:
        return list(csv.DictReader(f))


def test_offline_run_has_the_config_every_metrics_row_and_the_summary(tmp_path):
    run = tmp_path / "run"
    result = train(load_config(tiny(total_steps=96, logger={"name": "wandb"})), run, echo=lambda _: None)
    run_id = (run / "wandb_id.txt").read_text().strip()
    (offline,) = offline_runs(run)
    assert offline.name.endswith(f"-{run_id}")
    config, history, summary = read_run(offline)

    # the run's own config, as config.yaml holds it
    assert config["algo"]["name"] == "ppo_lag" and config["algo"]["cost_limit"] == 0.2
    assert config["env"]["max_steps"] == 12 and config["seed"] == 0 and config["logger"]["mode"] == "offline"
    assert config["resume"] is None

    # one history row per metrics.csv row, same numbers, against the env step
    rows = csv_rows(run)
    assert [h["step"] for h in history] == [int(r["step"]) for r in rows] == [32, 64, 96]
    for h, r in zip(history, rows):
        for name in ("episode_return", "episode_cost", "lagrange_multiplier", "loss_pi"):
            if r[name] not in ("", "nan"):
                assert h[name] == pytest.approx(float(r[name]), rel=1e-12)
        assert "iteration" not in h  # the x axis is the env step

    # eval.json's contents as the run's summary
    saved = json.loads((run / "eval.json").read_text())
    for key in ("episode_return", "episode_return_std", "episode_cost", "goal_reached", "train_time_s", "steps"):
        assert summary[key] == pytest.approx(saved[key]) == pytest.approx(result[key])


def test_a_resume_continues_under_the_same_wandb_id(tmp_path):
    run = tmp_path / "run"
    train(load_config(tiny(total_steps=64, logger={"name": "wandb"})), run, echo=lambda _: None)
    run_id = (run / "wandb_id.txt").read_text().strip()
    # wandb names an offline run's directory by the second it starts; a second session in the same
    # second gets a "-1" suffix and shares its files, so keep the two sessions a second apart.
    time.sleep(1.1)
    train(load_config(tiny(total_steps=128, logger={"name": "wandb"}, resume=str(run))), echo=lambda _: None)
    assert (run / "wandb_id.txt").read_text().strip() == run_id
    first, second = offline_runs(run)  # offline, each session writes its own directory with that id
    assert first.name.endswith(run_id) and second.name.endswith(run_id)
    assert [h["step"] for h in read_run(first)[1]] == [32, 64]
    assert [h["step"] for h in read_run(second)[1]] == [96, 128]


def test_the_logger_group_defaults_to_offline():
    cfg = compose_config(["logger=wandb"])
    assert (cfg.logger.name, cfg.logger.project, cfg.logger.entity, cfg.logger.mode) == (
        "wandb",
        "cmdp_rl",
        None,
        "offline",
    )


def test_missing_wandb_is_a_one_line_config_error(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else real(name, *a))
    with pytest.raises(ConfigError) as err:
        load_config(tiny(logger={"name": "wandb"}))
    assert str(err.value) == "logger.name: logger=wandb needs the wandb package: pip install 'cmdp_rl[wandb]'"


def test_csv_runs_write_no_wandb_files(tmp_path):
    train(load_config(tiny(total_steps=32)), tmp_path, echo=lambda _: None)
    assert not (tmp_path / "wandb").exists() and not (tmp_path / "wandb_id.txt").exists()


def test_a_run_left_open_by_a_failed_train_is_finished_by_the_next(tmp_path):
    from cmdp_rl.report.metrics import WandbRun

    dirs = [tmp_path / "a", tmp_path / "b"]
    for d in dirs:
        d.mkdir()
    first = WandbRun(dirs[0], "cmdp_rl", None, "offline", {"seed": 0})
    first.start(resume=False)
    first.log({"iteration": 1, "step": 32, "episode_return": 0.5}, ["iteration", "step", "episode_return"])
    second = WandbRun(dirs[1], "cmdp_rl", None, "offline", {"seed": 1})
    second.start(resume=False)  # without finish(): as after an exception in train()
    assert second.run.id != first.run.id
    second.finish({"episode_return": 0.25})
    (log,) = offline_runs(dirs[0])[0].glob("run-*.wandb")
    assert records(log)[-1].WhichOneof("record_type") == "exit"  # the first run was closed, not reused
    assert read_run(offline_runs(dirs[1])[0])[2]["episode_return"] == 0.25
    assert [h["step"] for h in read_run(offline_runs(dirs[0])[0])[1]] == [32]
