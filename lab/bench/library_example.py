"""Run the library guide's example (docs/guide/library.md, "Using it as a library") exactly as written and print
its wall time.

    python experiments/benchmarks/library_example.py                 # as written (load_config applies threads=1)
    python experiments/benchmarks/library_example.py --compare       # also: torch's default thread count, and
                                                          # each with one other busy process beside it

The example builds its pieces itself, not through ``train``; ``load_config`` sets torch's thread
count from the config's ``threads`` (``cmdp_rl/config/threads.py``), so the example runs as fast as
``train.py``. ``--compare`` shows what it would cost without that: the same code with
``apply_threads`` made a no-op, so torch keeps its default (one thread per core).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the checkout: its train.py, Makefile, docs/ and multirun/


def readme_example(readme: Path = ROOT / "docs" / "guide" / "library.md") -> str:
    """The first python block under the "Using it as a library" heading of the guide's library page."""
    text = readme.read_text()
    section = text[text.index("## Using it as a library") :]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def _child(default_threads: bool) -> None:
    if default_threads:
        import cmdp_rl.config.threads

        cmdp_rl.config.threads.apply_threads = lambda cfg: None  # noqa: E731 - what the example did before
        import cmdp_rl.config.run_config

        cmdp_rl.config.run_config.apply_threads = cmdp_rl.config.threads.apply_threads
    code = readme_example()
    t0 = time.perf_counter()
    exec(compile(code, "docs/guide/library.md", "exec"), {"__name__": "__example__"})
    import torch

    print(f"WALL {time.perf_counter() - t0:.2f} THREADS {torch.get_num_threads()}", flush=True)


def run(default_threads: bool, busy: bool) -> tuple[float, int]:
    """One run of the example in a fresh process; with ``busy``, one CPU-bound process beside it."""
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
    try:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        cmd = [sys.executable, __file__, "--child"] + (["--default-threads"] if default_threads else [])
        out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, check=True).stdout
    finally:
        if spinner is not None:
            spinner.kill()
            spinner.wait()
    wall, threads = re.search(r"WALL (\S+) THREADS (\d+)", out).groups()
    return float(wall), int(threads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--compare", action="store_true", help="also torch's default threads, and a busy neighbour")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--default-threads", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _child(args.default_threads)
        return
    cases = [(False, False)] + ([(True, False), (False, True), (True, True)] if args.compare else [])
    print(f"{os.cpu_count()} cores, load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for default_threads, busy in cases:
        wall, threads = run(default_threads, busy)
        how = "torch default threads" if default_threads else "as written (config threads)"
        print(
            f"{how:<28} | {'one busy process beside it' if busy else 'alone':<26} | "
            f"torch threads {threads} | {wall:6.1f} s"
        )
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
