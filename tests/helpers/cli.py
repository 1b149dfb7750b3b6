"""``python train.py ARGS`` run inside the test's process: :func:`cmdp_rl.cli.train.main` (all that train.py
calls) with ``sys.argv`` set, its exit status, stdout and stderr returned as ``subprocess.run`` returns them.

Why: a new interpreter spends seconds of CPU importing torch, TorchRL and SciPy before train.py reads its first
argument, and many tests only check what the command says and writes (a config error's one line and exit 2, a
refused resume). A check that needs a process of its own runs ``train.py`` in a subprocess instead: a directory
lock held by another process, a kill, a sweep's launcher, the interpreter's start (tests/test_run_ownership.py,
tests/test_resume.py's SIGKILL, tests/test_sweep_launchers.py, tests/test_train_cli.py's runs).
"""

import contextlib
import io
import subprocess
import sys

from cmdp_rl.cli import train as train_cli
from cmdp_rl.run import ownership

# Hydra's logging configs (a train.log and console handlers) go through logging.config.dictConfig, which closes
# every handler of the process first, pytest's own log capture among them: "I/O operation on closed file" in the
# test's teardown. In the test's process Hydra configures no logging; nothing checked here is a log line.
NO_LOGGING = ("hydra/job_logging=none", "hydra/hydra_logging=none")


def train_py(*args: str) -> subprocess.CompletedProcess:
    """Run ``train.py *args`` here; stdout and stderr are what the command printed (Hydra logs nothing here)."""
    held = set(ownership._held)
    out, err = io.StringIO(), io.StringIO()
    argv, sys.argv = sys.argv, ["train.py", *args, *NO_LOGGING]
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                train_cli.main()
            except SystemExit as exc:  # how the command ends on an error (exit 2, 3), or Hydra on a traceback (1)
                code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    finally:
        sys.argv = argv
        # What the process's end would undo: the Hydra callback's claim on the run directory (kept for the life of
        # train.py's process, cmdp_rl/run/hydra_callbacks.py).
        for path in set(ownership._held) - held:
            while path in ownership._held:
                ownership.release(path)
    return subprocess.CompletedProcess(["train.py", *args], code, out.getvalue(), err.getvalue())
