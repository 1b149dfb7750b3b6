"""A benchmark campaign: a queue of training runs that survives restarts, and the small records it leaves.

A campaign file (YAML) lists groups of runs, each group a product of algorithms x tasks x seeds at one step
count, with extra train.py options, or a peer toolkit's runs (``peer: omnisafe``)::

    name: safety_gym_2m
    results: docs/results/safety_gym      # one JSON record per finished run (committed)
    work: outputs/campaigns                # the run directories (checkpoints, metrics.csv; never committed)
    eval_episodes: 50
    mark_every: 100000                     # the training curve's step marks
    groups:
      - {env: safe_nav, tasks: [PointGoal1], algos: [ppo, ppo_lag], seeds: [0, 1, 2], steps: 2000000}
      - {peer: omnisafe, tasks: [SafetyPointGoal1-v0], algos: [PPOLag], seeds: [0], steps: 1000000}

``python experiments/benchmarks/campaign.py <campaign> --jobs 1`` works through it under ``nice``:

- a run whose record exists is finished and skipped, on any machine that has the records;
- a run directory with a checkpoint is resumed from it (``train.py resume=<dir>``: runs resume bit for bit); one
  without (killed before its first checkpoint) starts again; the peer's runs cannot resume and start again;
- each run's sessions (start, resume; wall and CPU seconds, the load average sampled every ``LOAD_EVERY`` s, the
  machine) are kept in its directory as they go, so a killed session still counts in the record;
- when a run ends, its record is written: options, seed, commit, the resolved config, the training curve (the
  last 100 training episodes at every mark), the deployed policy's evaluation in both modes with intervals,
  the time and the load. Nothing else of the run goes into ``results``.

The report (``lab/bench/campaign_report.py``) reads the records only.
"""

from __future__ import annotations

import ctypes
import dataclasses
import datetime as dt
import hashlib
import json
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator, Sequence

import yaml

ROOT = Path(__file__).resolve().parents[2]  # the checkout: train.py, docs/, outputs/
LOAD_EVERY = 30.0  # seconds between load samples of a running session
SESSIONS = "campaign_sessions.json"  # in the run directory: its sessions so far
PEER_RESULT = "peer_result.json"  # in a peer run's directory: what lab/bench/omnisafe_peer.py wrote
RECORD_FORMAT = 1
# What a record keeps of each evaluation mode (eval.json's keys, run/evaluation.py and report/intervals.py).
EVAL_KEYS = (
    "episodes",
    "episode_return",
    "episode_return_std",
    "episode_return_ci95",
    "episode_cost",
    "episode_cost_std",
    "episode_cost_ci95",
    "episode_cost_ucb95",
    "episode_cost_max",
    "violations",
    "violation_rate",
    "violation_rate_ucb95",
    "episode_length",
)


class CampaignError(ValueError):
    """A campaign file that cannot be run: one line naming the field."""


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One run of a campaign: ``algo`` on ``task`` of ``env`` for ``steps`` env steps under ``seed``, with
    ``options`` (train.py overrides); ``peer`` names another toolkit that runs it instead (``omnisafe``)."""

    algo: str
    env: str
    task: str
    seed: int
    steps: int
    options: tuple[str, ...] = ()
    peer: str | None = None

    @property
    def id(self) -> str:
        """The record's and run directory's name: readable, and unique per options."""
        who = self.peer or self.env
        extra = ""
        if self.options:
            extra = "-" + hashlib.sha1(" ".join(self.options).encode()).hexdigest()[:8]
        return f"{who}-{self.task}-{self.algo}-{_steps_label(self.steps)}-s{self.seed}{extra}"

    def train_command(self, run_dir: Path, resume: bool, eval_episodes: int) -> list[str]:
        """The train.py command line that (re)starts this run in ``run_dir``."""
        if resume:
            return [sys.executable, str(ROOT / "train.py"), f"resume={run_dir}"]
        task = [f"env.task={self.task}"] if self.task else []
        return [
            sys.executable,
            str(ROOT / "train.py"),
            f"algo={self.algo}",
            f"env={self.env}",
            *task,
            f"seed={self.seed}",
            f"total_steps={self.steps}",
            f"eval_episodes={eval_episodes}",
            *self.options,
            f"hydra.run.dir={run_dir}",
            "overwrite=true",  # a directory without a checkpoint holds nothing to keep: a killed first session's
        ]


def _steps_label(steps: int) -> str:
    for unit, size in (("M", 1_000_000), ("k", 1_000)):
        if steps % size == 0:
            return f"{steps // size}{unit}"
    return str(steps)


@dataclasses.dataclass
class Campaign:
    name: str
    path: Path
    results: Path
    work: Path
    runs: list[RunSpec]
    eval_episodes: int = 50
    mark_every: int = 100_000
    peer_python: dict[str, str] = dataclasses.field(default_factory=dict)


def load_campaign(path: str | Path) -> Campaign:
    """A campaign file's runs, expanded; paths relative to the checkout. A bad field is a :class:`CampaignError`."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise CampaignError(f"campaign {path}: cannot read it ({exc})") from exc
    if not isinstance(raw, dict) or not isinstance(raw.get("groups"), list):
        raise CampaignError(f"campaign {path}: groups must be a list of run groups")
    runs = [run for i, group in enumerate(raw["groups"]) for run in _expand(group, f"{path}: groups[{i}]")]
    ids = [r.id for r in runs]
    if len(set(ids)) != len(ids):
        raise CampaignError(f"campaign {path}: a run is listed twice ({_first_duplicate(ids)})")
    root = lambda p: Path(p) if Path(p).is_absolute() else ROOT / p  # noqa: E731
    return Campaign(
        name=str(raw.get("name", path.stem)),
        path=path,
        results=root(raw.get("results", "docs/results/safety_gym")),
        work=root(raw.get("work", "outputs/campaigns")),
        runs=runs,
        eval_episodes=_positive(raw.get("eval_episodes", 50), f"{path}: eval_episodes"),
        mark_every=_positive(raw.get("mark_every", 100_000), f"{path}: mark_every"),
        peer_python={k: str(v) for k, v in (raw.get("peer_python") or {}).items()},
    )


def _expand(group: Any, where: str) -> Iterator[RunSpec]:
    if not isinstance(group, dict):
        raise CampaignError(f"{where} must be a mapping")
    known = {"env", "tasks", "algos", "seeds", "steps", "options", "peer"}
    unknown = sorted(set(group) - known)
    if unknown:
        raise CampaignError(f"{where}.{unknown[0]} is not a field; the fields are {', '.join(sorted(known))}")
    peer = group.get("peer")
    if peer not in (None, "omnisafe"):
        raise CampaignError(f"{where}.peer must be omnisafe or absent, got {peer!r}")
    steps = _positive(group.get("steps"), f"{where}.steps")
    options = tuple(str(o) for o in group.get("options") or ())
    for field in ("algos", "seeds"):
        if not isinstance(group.get(field), list) or not group[field]:
            raise CampaignError(f"{where}.{field} must be a non-empty list")
    env = str(group.get("env", "omnisafe" if peer else "safe_nav"))
    for task in group.get("tasks") or [""]:
        for algo in group["algos"]:
            for seed in group["seeds"]:
                yield RunSpec(str(algo), env, str(task), int(seed), steps, options, peer)


def _positive(value: Any, where: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise CampaignError(f"{where} must be a positive integer, got {value!r}")
    return value


def _first_duplicate(ids: Sequence[str]) -> str:
    seen: set[str] = set()
    for i in ids:
        if i in seen:
            return i
        seen.add(i)
    return ""


# --- running ---------------------------------------------------------------------------------------


def record_path(campaign: Campaign, run: RunSpec) -> Path:
    return campaign.results / f"{run.id}.json"


def pending(campaign: Campaign) -> list[RunSpec]:
    """The runs without a record, in the campaign's order."""
    return [r for r in campaign.runs if not record_path(campaign, r).is_file()]


def _die_with_parent() -> None:
    """In the child, before exec: the kernel kills it when the runner dies, however (prctl PR_SET_PDEATHSIG),
    so that a killed runner leaves no orphan training on a run directory the next runner must resume."""
    libc = ctypes.CDLL("libc.so.6", use_errno=True)
    libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1


@dataclasses.dataclass
class Session:
    """One process that ran (part of) a run: how it started, how long, on what, at what load."""

    kind: str  # start | resume | evaluate
    started: str
    wall_s: float = 0.0
    cpu_s: float = 0.0
    load: list[float] = dataclasses.field(default_factory=list)  # 1-minute load averages, sampled
    host: str = dataclasses.field(default_factory=platform.node)
    cpu: str = dataclasses.field(default_factory=lambda: cpu_model())
    cores: int = dataclasses.field(default_factory=lambda: os.cpu_count() or 0)
    exit: int | None = None


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def read_sessions(run_dir: Path) -> list[dict[str, Any]]:
    try:
        return json.loads((run_dir / SESSIONS).read_text())
    except (OSError, ValueError):
        return []


def _write_sessions(run_dir: Path, sessions: list[dict[str, Any]]) -> None:
    tmp = run_dir / (SESSIONS + ".tmp")
    tmp.write_text(json.dumps(sessions, indent=1))
    os.replace(tmp, run_dir / SESSIONS)


def run_session(command: list[str], run_dir: Path, kind: str, niceness: int, log: Path) -> int:
    """Run ``command`` to its end at ``niceness``, recording the session in ``run_dir`` as it goes (a kill of
    this process leaves the session's time so far there); returns its exit status."""
    run_dir.mkdir(parents=True, exist_ok=True)
    earlier = read_sessions(run_dir)
    session = Session(kind, dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"))

    def before() -> None:
        _die_with_parent()
        if niceness:
            os.nice(niceness)

    start, cpu_before = time.perf_counter(), _children_cpu()
    with open(log, "a") as out:
        proc = subprocess.Popen(command, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, preexec_fn=before)
        while True:
            session.load.append(round(os.getloadavg()[0], 2))
            session.wall_s = time.perf_counter() - start
            _write_sessions(run_dir, [*earlier, dataclasses.asdict(session)])
            try:
                session.exit = proc.wait(timeout=LOAD_EVERY)
                break
            except subprocess.TimeoutExpired:
                continue
    session.wall_s = time.perf_counter() - start
    session.cpu_s = _children_cpu() - cpu_before
    _write_sessions(run_dir, [*earlier, dataclasses.asdict(session)])
    return session.exit


def _children_cpu() -> float:
    usage = os.times()
    return usage.children_user + usage.children_system


def run_one(campaign: Campaign, run: RunSpec, niceness: int, echo: Any = print) -> Path | None:
    """Train (or resume, or finish evaluating) ``run``, then write its record; returns the record's path, or
    None where the run failed (its log says why)."""
    run_dir = campaign.work / campaign.name / run.id
    log = campaign.work / campaign.name / f"{run.id}.log"
    run_dir.mkdir(parents=True, exist_ok=True)
    if run.peer:
        kind, command = "start", peer_command(campaign, run, run_dir)
    else:
        resume = (run_dir / "checkpoint.pt").is_file()
        kind = "resume" if resume else "start"
        command = run.train_command(run_dir, resume, campaign.eval_episodes)
    echo(f"{run.id}: {kind} ({' '.join(command[1:])})")
    status = run_session(command, run_dir, kind, niceness, log)
    if status != 0:
        echo(f"{run.id}: exit status {status}; see {log}")
        return None
    record = make_record(campaign, run, run_dir)
    path = record_path(campaign, run)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    echo(f"{run.id}: record {path}")
    return path


def peer_command(campaign: Campaign, run: RunSpec, run_dir: Path) -> list[str]:
    python = campaign.peer_python.get(run.peer or "") or os.environ.get("OMNISAFE_PYTHON")
    if not python:
        raise CampaignError(f"{run.id}: no Python for peer {run.peer} (campaign peer_python, or OMNISAFE_PYTHON)")
    script = ROOT / "lab" / "bench" / "omnisafe_peer.py"
    return [python, str(script), run.algo, run.task, str(run.steps), str(run.seed), str(run_dir)]


def run_campaign(campaign: Campaign, jobs: int = 1, niceness: int = 10, echo: Any = print) -> int:
    """Work through the runs without a record, ``jobs`` at a time; returns how many failed."""
    todo = pending(campaign)
    echo(f"campaign {campaign.name}: {len(campaign.runs) - len(todo)} of {len(campaign.runs)} runs have records")
    if jobs <= 1:
        return sum(run_one(campaign, r, niceness, echo) is None for r in todo)
    from concurrent.futures import ThreadPoolExecutor  # threads: each only waits on its own process

    with ThreadPoolExecutor(jobs) as pool:
        return sum(p is None for p in pool.map(lambda r: run_one(campaign, r, niceness, echo), todo))


# --- the record ------------------------------------------------------------------------------------


def git_commit() -> dict[str, Any]:
    def git(*args: str) -> str:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
        return out.stdout.strip() if out.returncode == 0 else ""

    return {"commit": git("rev-parse", "HEAD") or None, "dirty": bool(git("status", "--porcelain", "--", "cmdp_rl"))}


def make_record(campaign: Campaign, run: RunSpec, run_dir: Path) -> dict[str, Any]:
    """The record of a finished run from its directory (cmdp_rl's outputs, or the peer's ``peer_result.json``)."""
    sessions = read_sessions(run_dir)
    loads = [x for s in sessions for x in s.get("load", [])]
    body = _peer_body(campaign, run, run_dir) if run.peer else _own_body(campaign, run, run_dir)
    return {
        "format": RECORD_FORMAT,
        "id": run.id,
        "campaign": campaign.name,
        "toolkit": run.peer or "cmdp_rl",
        "algo": run.algo,
        "env": run.env,
        "task": run.task,
        "seed": run.seed,
        "steps": run.steps,
        "options": list(run.options),
        **git_commit(),
        "date": dt.date.today().isoformat(),
        **body,
        "time": {
            "wall_s": round(sum(s.get("wall_s", 0.0) for s in sessions), 1),
            "cpu_s": round(sum(s.get("cpu_s", 0.0) for s in sessions), 1),
            "sessions": sessions,
        },
        "load": _load_summary(loads),
        "machine": {"cpu": sessions[-1]["cpu"] if sessions else cpu_model(), "device": body.pop("device", "cpu")},
    }


def _load_summary(loads: Sequence[float]) -> dict[str, float] | None:
    if not loads:
        return None
    return {"min": min(loads), "mean": round(sum(loads) / len(loads), 2), "max": max(loads)}


def _own_body(campaign: Campaign, run: RunSpec, run_dir: Path) -> dict[str, Any]:
    from cmdp_rl.report.metrics import read_metrics, training_episodes

    result = json.loads((run_dir / "eval.json").read_text())
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    rows = read_metrics(run_dir / "metrics.csv")
    curve = [
        {"step": m, **(training_episodes([r for r in rows if r["step"] <= m]) or {})} for m in _marks(campaign, run)
    ]
    modes = result.get("modes") or {("mean_action" if result.get("deterministic") else "sampled"): result}
    return {
        "config": {k: config.get(k) for k in ("algo", "policy", "normalize", "deploy", "env", "rollout_steps")},
        "curve": curve,
        "evaluation": {
            "deployed": result.get("final_policy"),
            "mixture_deployed": result.get("mixture_deployed"),
            "headline": "mean_action" if result.get("deterministic") else "sampled",
            **{name: {k: r.get(k) for k in EVAL_KEYS} for name, r in modes.items()},
        },
        "training_episodes": result.get("training_episodes"),
        "train_time_s": result.get("train_time_s"),
        "device": _device(config),
    }


def _device(config: dict[str, Any]) -> str:
    """Where the run trained: its device, and the physics where it is not MuJoCo's C engine (env.physics=mjwarp)."""
    physics = (config.get("env") or {}).get("physics", "mujoco")
    return str(config.get("device", "cpu")) + ("" if physics == "mujoco" else f"/{physics}")


def _marks(campaign: Campaign, run: RunSpec) -> list[int]:
    return list(range(campaign.mark_every, run.steps + 1, campaign.mark_every))


def _peer_body(campaign: Campaign, run: RunSpec, run_dir: Path) -> dict[str, Any]:
    """A peer's record from its ``peer_result.json``: its logged training curve (OmniSafe's ``Metrics/EpRet``
    and ``EpCost``, the mean of its last 100 episodes, per epoch) read at the marks, and its deployed policy's
    episodes in both modes summarised by this toolkit's interval code, so both toolkits' cells are alike."""
    from cmdp_rl.report.intervals import summarize

    peer = json.loads((run_dir / PEER_RESULT).read_text())
    progress = peer["progress"]  # [{"step", "episode_return", "episode_cost"}] per epoch
    curve = []
    for mark in _marks(campaign, run):
        rows = [p for p in progress if p["step"] <= mark]
        curve.append({"step": mark, **({k: rows[-1][k] for k in ("episode_return", "episode_cost")} if rows else {})})
    evaluation: dict[str, Any] = {"deployed": "last", "headline": "sampled"}
    for name, eps in peer["evaluation"].items():  # {"sampled": {"returns": [...], "costs": [...]}, ...}
        returns, costs = eps["returns"], eps["costs"]
        est = summarize(returns, costs, 25.0)
        evaluation[name] = {
            "episodes": len(returns),
            "episode_return": sum(returns) / len(returns),
            "episode_cost": sum(costs) / len(costs),
            "episode_cost_max": max(costs),
            **{k: v for k, v in est.items() if k in EVAL_KEYS},
        }
    last = progress[-1] if progress else {}
    return {
        "config": {"omnisafe": peer.get("config", {})},
        "curve": curve,
        "evaluation": evaluation,
        "training_episodes": {k: last.get(k) for k in ("episode_return", "episode_cost")} if last else None,
        "train_time_s": peer.get("learn_s"),
    }


def import_run(campaign: Campaign, run_dir: Path, options: Sequence[str], echo: Any = print) -> Path:
    """A record for a run made elsewhere (a lent GPU's: lab/bench/gpu_figures.py item 6 keeps its config.yaml,
    metrics.csv and eval.json): its spec read from the config, ``options`` the overrides it ran with beyond
    algorithm, env, task, seed and steps. Its time is the run's training time; no session or load was recorded."""
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    env = config["env"]
    run = RunSpec(
        config["algo"]["name"], env["name"], env.get("task", ""), config["seed"], config["total_steps"], tuple(options)
    )
    record = make_record(campaign, run, run_dir)
    record["time"]["train_time_s"] = record.get("train_time_s")
    path = record_path(campaign, run)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    echo(f"{run.id}: record {path} (imported from {run_dir}, trained on {record['machine']['device']})")
    return path


# --- the command line ------------------------------------------------------------------------------

USAGE = """A benchmark campaign: a resumable queue of runs and the records they leave (docs/benchmarks.md).

    python experiments/benchmarks/campaign.py experiments/benchmarks/campaigns/safety_gym_2m.yaml --jobs 1
    python experiments/benchmarks/campaign.py CAMPAIGN --list          # each run: recorded, resumable or new
    python experiments/benchmarks/campaign.py CAMPAIGN --report        # docs/benchmarks.md's tables from records
    python experiments/benchmarks/campaign.py CAMPAIGN --import-run DIR --options +experiment=safe_nav_gpu
                                                                     # a record of a run made on a lent GPU
"""


def status_lines(campaign: Campaign) -> list[str]:
    lines = []
    for run in campaign.runs:
        run_dir = campaign.work / campaign.name / run.id
        if record_path(campaign, run).is_file():
            state = "recorded"
        elif (run_dir / "checkpoint.pt").is_file():
            state = "resumable"
        else:
            state = "new"
        lines.append(f"{state:>9}  {run.id}")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(description=USAGE, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("campaign", nargs="+", help="campaign files (YAML)")
    parser.add_argument("--jobs", type=int, default=1, help="runs side by side (default 1: one core stays free)")
    parser.add_argument("--nice", type=int, default=10, help="niceness of the runs (default 10; 0: none)")
    parser.add_argument("--list", action="store_true", help="list the runs and their state, run nothing")
    parser.add_argument("--report", action="store_true", help="write the report from the records, run nothing")
    parser.add_argument("--import-run", type=Path, help="record a run made elsewhere (its config.yaml, metrics, eval)")
    parser.add_argument("--options", nargs="*", default=[], help="with --import-run: the overrides it ran with")
    args = parser.parse_args(argv)
    try:
        campaigns = [load_campaign(p) for p in args.campaign]
    except CampaignError as exc:
        print(f"campaign error: {exc}", file=sys.stderr)
        return 2
    if args.list:
        for c in campaigns:
            print(f"{c.name}:", *status_lines(c), sep="\n")
        return 0
    if args.import_run:
        import_run(campaigns[0], args.import_run, args.options)
        return 0
    if args.report:
        from lab.bench.campaign_report import write_report

        for path in write_report(campaigns):
            print(f"wrote {path}")
        return 0
    failed = sum(run_campaign(c, args.jobs, args.nice) for c in campaigns)
    return 1 if failed else 0
