"""Converting a run directory written before the safe checkpoint format, once, on the user's word:
``python -m cmdp_rl.run.convert <run dir> [<run dir> ...]`` (docs/checkpoints.md). The rules that
bring an old checkpoint to the current layout are :mod:`cmdp_rl.run.migrations`; this module applies them
to a run's (or a population's and its agents') files."""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path
from typing import Callable

from torch import nn

from cmdp_rl.config.saved import CHECKPOINT, POPULATION_CHECKPOINT
from cmdp_rl.run.checkpoint import FORMAT_VERSION, CheckpointError, load_checkpoint, save_checkpoint
from cmdp_rl.run.migrations import migrate
from cmdp_rl.run.rundir import run_config


def convert_run(run_dir: str | Path, echo: Callable[[str], None] = print) -> Path:
    """Rewrite the checkpoint of ``run_dir`` (a run's or a population's, and its agents') in the current format, the
    old file kept as ``<name>.format<N>``. Reads it with the full unpickler: only for runs whose author you trust."""
    run = Path(run_dir)
    files = [run / POPULATION_CHECKPOINT] if (run / POPULATION_CHECKPOINT).is_file() else []
    files += sorted(run.glob(f"**/{CHECKPOINT}")) if files else [run / CHECKPOINT]
    if not files[0].is_file():
        raise CheckpointError(f"convert: no {CHECKPOINT} in {run}")
    for path in files:
        state = load_checkpoint(path, trust=True)
        if state["format"] == FORMAT_VERSION:
            echo(f"{path}: already format {FORMAT_VERSION}")
            continue
        agent = _run_agent(path.parent) if path.name == CHECKPOINT else None
        new = migrate(state, agent)
        old = path.with_name(f"{path.name}.format{state['format']}")
        shutil.copyfile(path, old)
        save_checkpoint(path, {k: v for k, v in new.items() if k != "format"})
        echo(f"{path}: format {state['format']} -> {FORMAT_VERSION} (the old file kept as {old.name})")
    return run


def _run_agent(run_dir: Path) -> nn.Module:
    """The agent the run's config builds (its networks' names are what old ones convert to)."""
    from cmdp_rl.envs import make_eval_env
    from cmdp_rl.policies import make_agent
    from cmdp_rl.rollout.normalization import Normalizers

    cfg = run_config(run_dir, "convert")
    env = make_eval_env(cfg.env, num_envs=1, algo=cfg.algo)
    try:
        norm = Normalizers.from_config(
            cfg.normalize, env.obs_dim, cfg.env.num_envs, cfg.algo.gamma, cfg.algo.cost_gamma
        )
        return make_agent(cfg.policy, env, norm)
    finally:
        env.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m cmdp_rl.run.convert",
        description="Rewrite old run directories' checkpoints in the current, safely loadable format. "
        "Reading an old checkpoint runs code from the file: convert only runs whose author you trust.",
    )
    parser.add_argument("runs", nargs="+", type=Path, help="run (or population) directories, each converted once")
    args = parser.parse_args(argv)
    try:
        for run in args.runs:
            convert_run(run)
    except (CheckpointError, KeyError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
