"""Per-iteration metrics: a CSV row each, TensorBoard scalars (``logger=tensorboard``) or a wandb run under the same
names against the env step, and the progress line. Columns: :data:`RUN_COLUMNS`, the algorithm's ``stats``,
:data:`SAFETY_COLUMNS` (any other name is an error); with K > 1 costs each :data:`PER_CONSTRAINT` quantity has a
column per cost, ``<name>/<cost name>`` (TensorBoard groups tags by the part before the slash)."""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import secrets
from collections import deque
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from cmdp_rl.config.run_config import TENSORBOARD_MISSING, WANDB_MISSING, RunConfig
from cmdp_rl.report.safety_metrics import per_constraint_values

WANDB_ID = "wandb_id.txt"  # the wandb run's id, for a resume to continue the same run
_SINGLE = ("cost_0",)  # the cost names of an env with one cost (its columns keep plain names)

# lagrange_multiplier: the lambda in force (0 for unconstrained PPO).
RUN_COLUMNS = [
    "iteration",
    "step",
    "episode_return",
    "episode_cost",
    "episode_length",
    "episodes",
    "lagrange_multiplier",
    "cost_limit",
    "sps",
    "time_s",
]
SAFETY_COLUMNS = ["cost_rate", "normalized_return", "normalized_violation", "normalized_cost_rate"]
PER_CONSTRAINT = (
    "episode_cost",
    "lagrange_multiplier",
    "cost_limit",
    "cost_rate",
    "normalized_violation",
    "normalized_cost_rate",
)


def constraint_name(name: str, cost_name: str, num_costs: int) -> str:
    """The column (or eval.json key) of ``name`` for one constraint: ``name`` with one cost, else ``name/cost_name``."""
    return name if num_costs == 1 else f"{name}/{cost_name}"


def spread(row: dict[str, Any], cost_names: Sequence[str] = _SINGLE) -> dict[str, Any]:
    """``row`` with each per-constraint value (a list of K, or one number for all) as its K columns."""
    k = len(cost_names)
    out: dict[str, Any] = {}
    for name, value in row.items():
        if name not in PER_CONSTRAINT:
            out[name] = value
            continue
        values = list(value) if isinstance(value, (list, tuple)) else [value] * k
        if len(values) != k:
            raise ValueError(f"metrics: {name} has {len(values)} values for {k} costs")
        out.update({constraint_name(name, c, k): v for c, v in zip(cost_names, values)})
    return out


def columns(stats: Sequence[str], cost_names: Sequence[str] = _SINGLE) -> list[str]:
    """A run's metrics.csv columns, for an algorithm that declares ``stats``, on an env with ``cost_names``."""
    names = [*RUN_COLUMNS, *(s for s in stats if s not in RUN_COLUMNS and s not in SAFETY_COLUMNS), *SAFETY_COLUMNS]
    out: list[str] = []
    for n in names:
        out += [constraint_name(n, c, len(cost_names)) for c in cost_names] if n in PER_CONSTRAINT else [n]
    return out


def truncate_metrics(path: str | Path, iteration: int) -> list[str]:
    """Keep the header and rows 1..``iteration`` (a resume from there) and return the header; a missing or
    misordered row is a ``ValueError`` (rows are synced before each checkpoint: the file was edited or lost)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path} is missing; the checkpoint is at iteration {iteration}")
    # Every complete line ends with a newline; what follows the last one is a row cut by a kill.
    lines = path.read_text().split("\n")[:-1]
    if not lines:
        raise ValueError(f"{path} has no header")
    header = next(csv.reader([lines[0]]))
    rows = lines[1 : iteration + 1]
    found = [next(csv.reader([r]))[0] for r in rows]
    if found != [str(i) for i in range(1, iteration + 1)]:
        raise ValueError(
            f"{path} does not hold rows 1..{iteration} in order (found iterations "
            f"{found[:3]}...{found[-3:]}); the checkpoint is at iteration {iteration}"
        )
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join([lines[0], *rows]) + "\n")
    os.replace(tmp, path)
    return header


# The progress line's window of finished episodes (SB3's ep_rew_mean, OmniSafe's window_lens): a task whose
# episodes end every few iterations never shows n/a once one has ended. metrics.csv keeps each iteration's own.
RECENT_EPISODES = 100


def read_metrics(path: str | Path) -> list[dict[str, float]]:
    """metrics.csv's rows as floats (blank: NaN) up to any row a kill cut short; none without the file."""
    path = Path(path)
    if not path.is_file():
        return []
    rows = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            try:
                rows.append({k: float(v) if v not in ("", None) else float("nan") for k, v in row.items()})
            except (TypeError, ValueError):
                break  # a row cut short by a kill: keep what came before it
    return rows


def training_episodes(rows: Sequence[Mapping[str, float]], episodes: int = RECENT_EPISODES) -> dict[str, Any] | None:
    """The training episodes' mean return and cost (each ``episode_cost*`` column) over the last iterations of
    ``rows`` (metrics.csv's) that hold at least ``episodes`` finished episodes, whole iterations only, each episode
    counted once: what published learning curves show (OmniSafe's ``Metrics/EpRet`` is its last 100 episodes).
    ``episodes`` counts them; fewer where the run has not finished that many. None before the first ends."""
    taken: list[Mapping[str, float]] = []
    for row in reversed(rows):
        if sum(r["episodes"] for r in taken) >= episodes:
            break
        if row.get("episodes", 0) > 0:
            taken.append(row)
    count = sum(r["episodes"] for r in taken)
    if not count:
        return None
    names = [k for k in taken[0] if k == "episode_cost" or k.startswith("episode_cost/")]
    mean = {k: sum(r[k] * r["episodes"] for r in taken) / count for k in ("episode_return", *names)}
    return {**mean, "episodes": int(count), "first_step": int(taken[-1]["step"]), "last_step": int(taken[0]["step"])}


class RecentEpisodes:
    """The last :data:`RECENT_EPISODES` finished episodes' returns and costs (K per episode)."""

    def __init__(self, size: int = RECENT_EPISODES) -> None:
        self.returns: deque[float] = deque(maxlen=size)
        self.costs: deque[tuple[float, ...]] = deque(maxlen=size)

    def add(self, returns: Sequence[float], costs: Sequence[Sequence[float]]) -> None:
        self.returns.extend(float(r) for r in returns)
        self.costs.extend(tuple(float(c) for c in row) for row in costs)

    def __len__(self) -> int:
        return len(self.returns)

    def over(self, row: dict[str, Any]) -> dict[str, Any]:
        """``row`` with its return and cost columns replaced by the window's means (as it is while empty)."""
        if not len(self):
            return row
        n = len(self.returns)
        names = ["episode_cost"] if "episode_cost" in row else [k for k in row if k.startswith("episode_cost/")]
        costs = dict(zip(names, (sum(col) / n for col in zip(*self.costs))))
        return {**row, "episode_return": sum(self.returns) / n, **costs}


class MetricsLogger:
    """One CSV row per iteration and a progress line every ``log_interval``. ``resume_iteration``: continue the
    file (:func:`truncate_metrics`); ``tensorboard_dir``: the numbers as scalars at ``step``, ``resume_step``
    hiding what a killed run wrote after its checkpoint; ``wandb``: :func:`wandb_for`."""

    def __init__(
        self,
        path: str | Path,
        fieldnames: Sequence[str],
        log_interval: int = 1,
        echo: Callable[[str], None] = print,
        resume_iteration: int | None = None,
        tensorboard_dir: str | Path | None = None,
        resume_step: int | None = None,
        wandb: WandbRun | None = None,
    ) -> None:
        self.path = Path(path)
        self.log_interval = log_interval
        self.echo = echo
        self._tb = None
        if tensorboard_dir is not None:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError as exc:
                raise ImportError(TENSORBOARD_MISSING) from exc
            purge = None if resume_step is None else resume_step + 1
            self._tb = SummaryWriter(str(tensorboard_dir), purge_step=purge)
        self.columns = list(fieldnames)
        if resume_iteration is not None:
            # The run keeps the columns it started with; one it lacks cannot be added: an error, not a dropped stat.
            self.columns = truncate_metrics(self.path, resume_iteration)
            missing = [c for c in fieldnames if c not in self.columns]
            if missing:
                raise ValueError(f"{self.path} has no column for {missing}, which this version logs")
        self._file = open(self.path, "w" if resume_iteration is None else "a", newline="")
        self._writer = csv.DictWriter(self._file, fieldnames=self.columns, lineterminator="\n")
        if resume_iteration is None:
            self._writer.writeheader()
        self._file.flush()
        self.recent = RecentEpisodes()
        self._wandb = wandb
        if wandb is not None:
            wandb.start(resume_iteration is not None)  # last: a resume refused above starts no wandb run

    def log(self, row: dict[str, Any], force_echo: bool = False, episodes: Mapping[str, Any] | None = None) -> None:
        """Write ``row``; ``episodes`` (finished ones: ``return`` [E], ``cost`` [E, K]) feed the progress line."""
        if episodes is not None:
            self.recent.add(episodes["return"].tolist(), episodes["cost"].tolist())
        unknown = [k for k in row if k not in self.columns]
        if unknown:
            raise ValueError(
                f"metrics: {unknown} are not columns of {self.path}; an algorithm must declare "
                f"every statistic it returns (its `stats`)"
            )
        self._writer.writerow(row)
        self._file.flush()
        if self._tb is not None:
            for name, value in scalars(row, self.columns).items():
                self._tb.add_scalar(name, value, global_step=row["step"])
        if self._wandb is not None:
            self._wandb.log(row, self.columns)
        if force_echo or row["iteration"] == 1 or row["iteration"] % self.log_interval == 0:
            self.echo(format_row(row, self.recent))

    def sync(self) -> None:
        """Force the rows to disk before each checkpoint: it never refers to a row a crash could lose."""
        self._file.flush()
        os.fsync(self._file.fileno())
        if self._tb is not None:
            self._tb.flush()

    def close(self) -> None:
        """Close the files; a wandb run stays open for :meth:`finish`'s summary."""
        self._file.close()
        if self._tb is not None:
            self._tb.close()

    def finish(self, summary: Mapping[str, Any]) -> None:
        """Attach the run's summary (eval.json) to the wandb run, which ends here."""
        if self._wandb is not None:
            self._wandb.finish(summary)


class WandbRun:
    """A wandb run (``logger=wandb``): config, a ``log`` per row against ``step``, summary; its id in ``wandb_id.txt``
    for a resume. Console capture is off: it would wrap stdout, which the progress lines own."""

    def __init__(self, run_dir: Path, project: str, entity: str | None, mode: str, config: dict[str, Any]) -> None:
        self.run_dir, self.project, self.entity, self.mode, self.config = run_dir, project, entity, mode, config
        self.run: Any = None

    def start(self, resume: bool) -> None:
        try:
            import wandb
        except ImportError as exc:
            raise ImportError(WANDB_MISSING) from exc
        id_file = self.run_dir / WANDB_ID
        if resume and id_file.is_file():
            run_id = id_file.read_text().strip()
        else:
            run_id = secrets.token_hex(4)  # as wandb makes them: 8 characters of [0-9a-z]
            id_file.write_text(run_id + "\n")
        self.run = wandb.init(
            project=self.project,
            entity=self.entity,
            mode=self.mode,
            dir=str(self.run_dir),
            id=run_id,
            resume="allow",
            name=self.run_dir.name,
            config=self.config,
            reinit="finish_previous",  # a train() that failed in this process left its run open
            settings=wandb.Settings(console="off", silent=True),
        )
        self.run.define_metric("step")
        self.run.define_metric("*", step_metric="step")

    def log(self, row: Mapping[str, Any], columns: Sequence[str]) -> None:
        self.run.log({"step": row["step"], **scalars(row, columns)})

    def finish(self, summary: Mapping[str, Any]) -> None:
        self.run.summary.update(dict(summary))
        self.run.finish()


def wandb_for(cfg: RunConfig, run_dir: str | Path) -> WandbRun | None:
    """The wandb run ``cfg.logger`` asks for (None unless ``logger=wandb``), with the run's own config."""
    if cfg.logger.name != "wandb":
        return None
    config = dataclasses.asdict(dataclasses.replace(cfg, resume=None))
    return WandbRun(Path(run_dir), cfg.logger.project, cfg.logger.entity, cfg.logger.mode, config)


def scalars(row: Mapping[str, Any], columns: Sequence[str]) -> dict[str, float]:
    """The row's finite numbers but ``iteration`` and ``step``: what TensorBoard and wandb plot."""
    return {k: v for k in columns[2:] if isinstance(v := row.get(k), (int, float)) and math.isfinite(v)}


def _fmt(x: float, spec: str) -> str:
    return "   n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def format_row(row: dict[str, Any], recent: RecentEpisodes | None = None) -> str:
    """The progress line: ``recent``'s window once it holds an episode, else the row's own (``lambda`` if reported)."""
    window = ""
    if recent is not None and len(recent):
        row, window = recent.over(row), f" | last {len(recent)} episodes"
    cost = "/".join(_fmt(c, ".2f") for c in per_constraint_values(row, "episode_cost"))
    lams = per_constraint_values(row, "lagrange_multiplier")
    lam = "/".join(_fmt(x, ".3f") for x in lams)
    if "episode_cost" in row:  # one constraint: fixed width
        cost = _fmt(row["episode_cost"], "6.2f")
        lam = _fmt(row["lagrange_multiplier"], "6.3f") if "lagrange_multiplier" in row else ""
    return (
        f"iter {row['iteration']:4d} | step {row['step']:>9,d} | {row['sps']:>8,.0f} steps/s"
        f" | return {_fmt(row['episode_return'], '7.3f')} | cost {cost}" + (f" | lambda {lam}" if lams else "") + window
    )
