"""A loss that turns NaN in a real train.py process: a clear stop, and nothing lost."""

import os
import subprocess
import sys

import torch
from helpers.runs import ROOT, cli_args, eval_result, metrics_rows, tiny

from cmdp_rl import load_config, train
from cmdp_rl.run.checkpoint import load_checkpoint

# Loaded at interpreter start through PYTHONPATH: from the CMDP_NAN_AT-th update on, the reward
# advantage every algorithm builds its policy advantage from is NaN, as after a numerical blow-up.
# It takes the variable out of the environment first: importing cmdp_rl starts Python subprocesses
# (mujoco's glfw probe), which would otherwise load this file again, and again.
POISON = """
import os
_nan_at = os.environ.pop("CMDP_NAN_AT", None)
if _nan_at:
    from cmdp_rl import keys
    from cmdp_rl.rollout.advantages import TwinGAE
    _original, _calls = TwinGAE.__call__, [0]

    def _poisoned(self, batch, ac):
        _calls[0] += 1
        out = _original(self, batch, ac)
        if _calls[0] >= int(_nan_at):
            out.set(keys.ADVANTAGE, out.get(keys.ADVANTAGE) * float("nan"))
        return out

    TwinGAE.__call__ = _poisoned
"""


def test_nan_stops_the_cli_run_and_its_last_checkpoint_evaluates_and_resumes(tmp_path, quiet):
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "sitecustomize.py").write_text(POISON)
    run = tmp_path / "run"
    # ROOT too: the poison must patch the cmdp_rl that train.py runs (this checkout's), which an
    # installed copy elsewhere would otherwise shadow at interpreter start.
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "site"), str(ROOT)]), "CMDP_NAN_AT": "6"}
    cfg = tiny()
    proc = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), *cli_args(cfg), f"hydra.run.dir={run}"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 3, proc.stderr[-2000:]
    assert "training stopped: iteration 6: loss_pi is nan" in proc.stderr
    assert f"the last good checkpoint is {run / 'checkpoint.pt'}" in proc.stderr
    state = load_checkpoint(run / "checkpoint.pt")
    assert state["iteration"] == 4  # checkpoints every 2 iterations: 5 was good but not saved
    assert all(torch.isfinite(t).all() for t in state["members"][0]["algo_state"]["networks"].values())
    assert [r["iteration"] for r in metrics_rows(run)] == ["1", "2", "3", "4", "5"]
    assert not (run / "eval.json").exists()

    # Resumed without the fault, the run is the one that never failed.
    train(load_config({**cfg, "resume": str(run)}), echo=quiet)
    whole = tmp_path / "whole"
    train(load_config(cfg), whole, echo=quiet)
    assert metrics_rows(run) == metrics_rows(whole)
    assert eval_result(run) == eval_result(whole)
