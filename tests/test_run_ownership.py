"""A run directory belongs to one run (cmdp_rl/run/ownership.py): a second run into a directory that
holds a run, finished or still running, stops with one line and changes none of its files; a lock
left by a killed process does not block; overwrite=true replaces; sweeps keep
their jobs apart."""

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers.cli import train_py
from helpers.runs import ROOT, metrics_rows, tiny

from cmdp_rl import load_config, train
from cmdp_rl.run.ownership import LOCK, RunDirTaken, acquire, release

# A run of seconds on the command line (2 iterations).
CLI = ["env.num_envs=2", "env.max_steps=10", "rollout_steps=8", "total_steps=32", "eval_episodes=1"]
CLI += ["algo.update_epochs=1", "algo.num_minibatches=1"]


def snapshot(root: Path) -> dict[str, str]:
    """Every file under ``root`` (hidden ones and .hydra/ included) and a hash of its bytes."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in root.rglob("*") if p.is_file()
    }


def hold_in_another_process(run_dir: Path, new_run: bool = True) -> subprocess.Popen:
    """A process that claims ``run_dir`` (as a new run, or as a resume of the run there) and keeps
    it, as a running run does."""
    code = (
        "import sys, time; from cmdp_rl.run.ownership import acquire; "
        "acquire(sys.argv[1], new_run=sys.argv[2] == 'new'); print('held', flush=True); time.sleep(600)"
    )
    args = [sys.executable, "-c", code, str(run_dir), "new" if new_run else "resume"]
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_run_into_a_finished_runs_directory_stops_with_one_line_and_changes_nothing(tmp_path):
    # train.py's main() in this process (helpers/cli.py): a finished run's directory is refused by what it holds,
    # whichever process asks; a live process's lock is the subject of the tests below, each with processes of its own.
    run = tmp_path / "run"
    assert train_py(*CLI, f"hydra.run.dir={run}").returncode == 0
    before = snapshot(run)
    assert "eval.json" in before and ".hydra/config.yaml" in before
    proc = train_py(*CLI, "seed=1", f"hydra.run.dir={run}")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr + proc.stdout
    assert proc.stderr.strip().splitlines() == [
        f"cannot write outputs: run directory {run} already holds a finished run: "
        f"continue it with resume={run}, or replace it with overwrite=true"
    ]
    assert snapshot(run) == before
    # As the line says: overwrite=true replaces it (a run of another length: 4 rows, not 2) ...
    assert train_py(*CLI, "total_steps=64", "overwrite=true", f"hydra.run.dir={run}").returncode == 0
    assert len(metrics_rows(run)) == 4


def test_train_refuses_a_directory_holding_a_run_unless_overwrite(tmp_path, quiet):
    cfg = tiny(total_steps=64)
    train(load_config(cfg), tmp_path, echo=quiet)
    before = snapshot(tmp_path)
    with pytest.raises(RunDirTaken, match="already holds a finished run: continue it with resume="):
        train(load_config(cfg), tmp_path, echo=quiet)
    assert snapshot(tmp_path) == before
    train(load_config({**cfg, "overwrite": True, "seed": 1}), tmp_path, echo=quiet)
    assert snapshot(tmp_path)["metrics.csv"] != before["metrics.csv"]


def test_a_run_into_a_running_runs_directory_is_refused_and_changes_nothing(tmp_path, quiet):
    run = tmp_path / "run"
    train(load_config(tiny(total_steps=64)), run, echo=quiet)
    (run / "eval.json").unlink()  # as a run still training looks
    holder = hold_in_another_process(run, new_run=False)  # as a resumed run holds it
    try:
        before = snapshot(run)
        for overwrite in (False, True):  # a live run is never replaced
            with pytest.raises(RunDirTaken, match=rf"is in use by a running run \(process {holder.pid}\)"):
                train(load_config(tiny(overwrite=overwrite)), run, echo=quiet)
        with pytest.raises(RunDirTaken, match="in use by a running run"):  # nor resumed under it
            train(load_config({**tiny(), "resume": str(run)}), echo=quiet)
        assert snapshot(run) == before
    finally:
        holder.kill()
        holder.wait()


def test_a_lock_left_by_a_killed_process_does_not_block(tmp_path, quiet):
    run = tmp_path / "run"
    holder = hold_in_another_process(run)
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    assert (run / LOCK).is_file()  # the file stays; the kernel dropped the lock with the process
    train(load_config(tiny(total_steps=64)), run, echo=quiet)
    assert len(metrics_rows(run)) == 2


def test_two_runs_started_together_into_one_directory_one_runs(tmp_path):
    run = tmp_path / "run"
    procs = [
        subprocess.Popen(
            [sys.executable, "train.py", *CLI, f"seed={s}", f"hydra.run.dir={run}"],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for s in (0, 1)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], outs
    refused = next(err for p, (_, err) in zip(procs, outs) if p.returncode == 2)
    assert "cannot write outputs: run directory" in refused
    rows = metrics_rows(run)  # one run's rows, whole: no torn or interleaved line
    assert [r["iteration"] for r in rows] == ["1", "2"]


def test_claims_within_one_process_are_counted(tmp_path):
    path = acquire(tmp_path / "run", new_run=True)
    assert acquire(tmp_path / "run", new_run=True) == path  # train() inside train.py's claim
    release(path)
    code = "import sys; from cmdp_rl.run.ownership import acquire; acquire(sys.argv[1], new_run=True)"
    busy = subprocess.run([sys.executable, "-c", code, str(path)], cwd=ROOT, capture_output=True, text=True)
    assert busy.returncode != 0 and "in use by a running run" in busy.stderr  # still held once
    release(path)
    assert subprocess.run([sys.executable, "-c", code, str(path)], cwd=ROOT).returncode == 0


def test_a_sweep_run_again_into_its_directory_leaves_its_jobs_alone(tmp_path):
    sweep = tmp_path / "sweep"
    assert train_py("-m", *CLI, "seed=0,1", f"hydra.sweep.dir={sweep}").returncode == 0  # in this process, as above
    before = snapshot(sweep)
    time.sleep(1)  # so that a rewritten file would differ in Hydra's timestamps too
    proc = train_py("-m", *CLI, "seed=0,1", f"hydra.sweep.dir={sweep}")
    assert proc.returncode != 0 and "already holds a finished run" in proc.stderr
    after = snapshot(sweep)
    jobs = {k: v for k, v in before.items() if k != "multirun.yaml"}  # Hydra's record of the sweep itself
    assert {k: after[k] for k in jobs} == jobs and set(after) == set(before)
