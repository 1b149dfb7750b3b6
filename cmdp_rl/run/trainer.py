"""A run: opened (``run/start.py``), trained by the loop (``run/loop.py``) on its one agent
(``run/kernel.AgentKernel``), then deployed, evaluated and written (``run/finish.py``).

``train.py`` is a thin Hydra front for ``cmdp_rl.train``, which trains a run here and a population in
``cmdp_rl/population/``; a user's script can call either.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from cmdp_rl.algos.base import per_constraint
from cmdp_rl.config.reference import load_reference
from cmdp_rl.config.run_config import RunConfig, budget_source, validate
from cmdp_rl.config.threads import apply_threads
from cmdp_rl.run.finish import finish_run
from cmdp_rl.run.kernel import AgentKernel
from cmdp_rl.run.loop import Observer, TrainingLoop
from cmdp_rl.run.ownership import acquire, release
from cmdp_rl.run.progress import Progress
from cmdp_rl.run.resume import load_resume_state
from cmdp_rl.run.rundir import RunDirError
from cmdp_rl.run.start import (  # noqa: F401 - run_config: lab/bench/campaign_report.py reads it here
    build_run,
    check_env_contracts,
    open_members,
    run_config,
    run_directory,
)


def train(
    cfg: RunConfig,
    out_dir: str | Path | None = None,
    echo: Callable[[str], None] = print,
    observers: Sequence[Observer] = (),
) -> dict[str, Any]:
    """Train as ``cfg`` says, writing ``config.yaml``, ``run_info.json``, ``metrics.csv``,
    ``checkpoint.pt`` and ``eval.json`` under ``out_dir`` (see ``cmdp_rl/run/rundir.py``). Returns the
    evaluation summary. Same config and seed, same numbers (on the same machine and versions).
    ``observers`` read each iteration's row (``run/loop.Observer``: a search's trial).

    With ``cfg.resume`` set to a run directory, continue that run from its last checkpoint, in that
    directory (``out_dir`` may be omitted). Its ``metrics.csv`` keeps the rows up to the
    checkpoint and continues after them; the run ends with the numbers it would have reached
    uninterrupted (see ``cmdp_rl/run/resume.py``).
    """
    validate(cfg)
    out = run_directory(cfg, out_dir)
    state = load_resume_state(cfg) if cfg.resume is not None else None
    apply_threads(cfg)
    check_env_contracts(cfg)  # before seeding: whatever randomness it uses, the run's is untouched
    env, agent, algo = build_run(cfg)
    # The budgets, one per cost (a list of the wrong length stops the run here, before any output).
    per_constraint(cfg.algo.cost_limit, "algo.cost_limit", env.cost_names)
    # After the resume and config checks (a mistyped resume path or a wrong-length budget is
    # reported, no directory created), before any training: the directory is this run's alone
    # (a new run refuses one that holds a run, unless overwrite) for as long as it trains.
    try:
        acquire(out, new_run=state is None, overwrite=cfg.overwrite)
    except RunDirError:
        env.close()
        raise
    try:
        return _train(cfg, out, AgentKernel(cfg, env, agent, algo), state, echo, observers)
    finally:
        release(out)


def _train(
    cfg: RunConfig,
    out: Path,
    kernel: AgentKernel,
    state: dict | None,
    echo: Callable[[str], None],
    observers: Sequence[Observer],
) -> dict[str, Any]:
    """The run in ``out`` on ``kernel``, from ``state`` (a resume's checkpoint) or anew: opened, trained,
    finished."""
    iterations = math.ceil(cfg.total_steps / kernel.per_iter)
    opened = open_members([cfg], [out], kernel, state, iterations, echo)
    start = time.perf_counter() - opened.elapsed
    reference, warnings = load_reference(cfg)
    for warning in warnings:
        echo(f"warning: {warning}")
    if state is not None:
        echo(f"resuming {out} from iteration {state['iteration']} (step {kernel.collector.total_steps:,})")
    echo(start_line(cfg, kernel, iterations, out))
    per_iter = kernel.per_iter
    progress = Progress(iterations * per_iter, (opened.first - 1) * per_iter, echo)  # a bar on a terminal
    opened.loggers[0].echo = progress.row_echo
    loop = TrainingLoop(
        [cfg],
        opened.saved,
        kernel,
        opened.loggers,
        opened.finals,
        out,
        iterations,
        echo=progress.write,
        member_echoes=[echo],
        reference=reference,
        observers=observers,
        progress=progress,
    )
    train_time = loop.run(opened.first, start)
    if opened.first > iterations:
        echo(f"{out}: training had already finished at iteration {opened.first - 1}; evaluating")
    return finish_run(cfg, out, kernel, opened.finals[0], opened.loggers[0], train_time, reference, echo)


def start_line(cfg: RunConfig, kernel: AgentKernel, iterations: int, out: Path) -> str:
    """What the run will do: the algorithm, the env, the iterations and the update's shape, the budget."""
    shape = f"{kernel.per_iter} steps ({cfg.rollout_steps} per env"
    described = cfg.algo.describe_update()
    if described:
        shape += f"; {described}"
    backend = getattr(cfg.env, "backend", None)  # only envs with several implementations have one
    where = f"{backend}, " if backend else ""
    cut = ", training episodes end past it (early_terminate)" if cfg.early_terminate else ""
    return (
        f"training {cfg.algo.name} on {cfg.env.name} ({where}{kernel.env.num_envs} envs): "
        f"{iterations} iterations of {shape}), cost limit {cfg.algo.cost_limit} ({budget_source(cfg)}){cut}, "
        f"outputs in {out}"
    )
