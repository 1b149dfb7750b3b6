"""Evaluate a trained run: ``cmdp-evaluate run=<run dir> [key=value ...]`` (``python evaluate.py`` in a checkout).

Loads the run's config and checkpoint, runs whole episodes and prints return, cost and length with
their spreads, then 95% intervals over the episodes: mean return and mean cost (BCa bootstrap), an
upper bound on mean cost, and the rate of episodes over the budget (exact binomial); see
docs/evaluation.md. With no options it repeats the run's own final evaluation (same episodes, same seed:
the numbers in its eval.json).

Options (cmdp_rl.config.run_config.EvalConfig):
  run=<dir>            the run directory (required)
  episodes=N           episodes to run (default: the run's eval_episodes)
  deterministic=B      true: the policy's mean action; false: sampled (default: the run's setting)
  seed=S               evaluation seed (default: the run's, seed + 1000003)
  checkpoint=<file>    load this checkpoint instead of the run's own (it must be of the same
                       algorithm and policy)
  plot=<file.png>      Reach1D: draw plot_episodes replayed episodes, true position and noisy
                       reading against time, wall, goal and collisions
  plot_episodes=N      episodes in the PNG (default 3)
  output=<file.json>   also write the results as JSON
  video=true           write mp4s of the policy through gymnasium's RecordVideo (needs
                       pip install 'cmdp_rl[video]'): Reach1D as a drawn frame (the torch backend
                       through its gym twin), the velocity tasks through MuJoCo; an env that
                       cannot render is refused. Same seed and policy mode as the evaluation.
  video_episodes=N     episodes recorded, one file each (default 1)
  video_dir=<dir>      where the mp4s go (default <run>/videos)
  video_steps=N        cut each recorded episode after N steps (default: whole episodes)
  trust_checkpoint=true  load a checkpoint of an older cmdp_rl format, which only Python's full
                       unpickler reads: THIS RUNS CODE FROM THE FILE; only for a run whose author
                       you trust. `python -m cmdp_rl.run.convert <run>` converts it once
                       instead (docs/checkpoints.md)

Video without a display: MuJoCo renders through EGL (MUJOCO_GL=egl is set when no DISPLAY is);
on Debian that needs libegl1, libegl-mesa0 and libgl1-mesa-dri (see cmdp_rl/report/video.py)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from cmdp_rl.config.run_config import ConfigError, EvalConfig
from cmdp_rl.config.validation import build
from cmdp_rl.report.reach1d_episodes import plot_reach1d, record_reach1d
from cmdp_rl.report.summary import constraints_of, interval_summary
from cmdp_rl.report.video import VideoError, make_render_env, record_video
from cmdp_rl.run.checkpoint import CheckpointError
from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET, evaluate
from cmdp_rl.run.rundir import load_trained, run_config


def _line(name: str, r: dict, fmt: str) -> str:
    m, s, lo, hi = (r[f"{name}{k}"] for k in ("", "_std", "_min", "_max"))
    return f"  {name:<15} {m:{fmt}} ± {s:{fmt}}   [min {lo:{fmt}}, max {hi:{fmt}}]"


def _cost_lines(r: dict, cost_names: tuple[str, ...], cost_limit: float | list[float]) -> list[str]:
    """The episode cost line, one per constraint (``cost/<name>``) for an env with K > 1 costs."""
    lines = []
    for name, suffix, d in constraints_of(cost_limit, cost_names):
        label = f"cost/{name}" if suffix else "episode_cost"
        own = {f"{label}{s}": r[f"episode_cost{s}{suffix}"] for s in ("", "_std", "_min", "_max")}
        lines.append(_line(label, own, ".2f") + f"   (limit {d})")
    return lines


def parse_options(argv: list[str]) -> EvalConfig:
    """The command's ``key=value`` options, checked (:class:`EvalConfig`); the run directory is not read yet."""
    bad = [a for a in argv if "=" not in a]
    if bad:
        raise ConfigError(f"evaluate: options are key=value, got {bad}; see --help")
    try:
        raw = OmegaConf.to_container(OmegaConf.from_dotlist(list(argv)))
    except OmegaConfBaseException as exc:
        raise ConfigError(f"evaluate: cannot parse {argv}: {exc}") from exc
    return build(EvalConfig, raw, "evaluate")


def main(argv: list[str] | None = None) -> int:
    """Run the command on ``argv`` (default: the process's arguments); returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if any(a in ("-h", "--help") for a in argv):
        print(__doc__)
        return 0
    try:
        opts = parse_options(argv)
        run_cfg = run_config(opts.run, "evaluate", opts.trust_checkpoint)
        episodes = opts.episodes or run_cfg.eval_episodes
        deterministic = run_cfg.eval_deterministic if opts.deterministic is None else opts.deterministic
        seed = run_cfg.seed + EVAL_SEED_OFFSET if opts.seed is None else opts.seed
        if opts.plot is not None and run_cfg.env.name != "reach1d":
            raise ConfigError(f"plot: episode plots are drawn for env=reach1d only, this run is env={run_cfg.env.name}")
        if opts.video:  # one frame now: an env or a machine that cannot render fails before the evaluation
            make_render_env(run_cfg.env).close()
        cfg, env, agent, iteration, step = load_trained(
            opts.run, opts.checkpoint, min(episodes, run_cfg.env.num_envs), opts.trust_checkpoint
        )
    except (ConfigError, CheckpointError, VideoError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    metric = getattr(cfg.env, "termination_metric", None)  # what the env says termination means
    result = evaluate(
        agent, env, episodes, deterministic, seed=seed, termination_metric=metric, cost_limit=cfg.algo.cost_limit
    )
    cost_names = env.cost_names
    env.close()
    result.update({"cost_limit": cfg.algo.cost_limit, "seed": seed, "checkpoint_iteration": iteration, "steps": step})
    result["final_policy"] = cfg.deploy.policy  # the deployed policy load_trained loaded (deploy_saved)
    mode = "deterministic" if deterministic else "stochastic"
    print(
        f"{opts.run}: {cfg.algo.name} on {cfg.env.name}, checkpoint of iteration {iteration} (step {step:,}); "
        f"{result['episodes']} episodes, {mode} policy, seed {seed}; deployed policy: {cfg.deploy.policy}"
    )
    _print_result(result, cost_names, cfg.algo.cost_limit, metric)
    if opts.output:
        Path(opts.output).write_text(json.dumps(result, indent=2))
        print(f"wrote {opts.output}")
    _record(opts, cfg, agent, deterministic, seed)
    return 0


def _print_result(result: dict, cost_names: tuple[str, ...], cost_limit: Any, metric: str | None) -> None:
    """The evaluation's lines: return, each cost against its budget, length, the termination rate, the intervals."""
    print(_line("episode_return", result, ".3f"))
    for line in _cost_lines(result, cost_names, cost_limit):
        print(line)
    print(_line("episode_length", result, ".1f"))
    if metric:
        print(f"  {metric:<15} {result[metric]:.0%}")
    for line in interval_summary(result, cost_limit, cost_names):
        print(f"  {line}")


def _record(opts: EvalConfig, cfg: Any, agent: Any, deterministic: bool, seed: int) -> None:
    """What ``plot=`` and ``video=true`` ask for: Reach1D's episode plot, the episodes' videos."""
    mode = "deterministic" if deterministic else "stochastic"
    if opts.plot:
        eps = record_reach1d(agent, cfg.env, opts.plot_episodes, deterministic, seed=seed)
        title = f"{opts.run}: {cfg.algo.name}, {mode} policy, cost limit {cfg.algo.cost_limit}"
        print(f"wrote {plot_reach1d(eps, cfg.env, opts.plot, title)}")
    if opts.video:
        video_dir = Path(opts.video_dir) if opts.video_dir else Path(opts.run) / "videos"
        for v in record_video(
            agent, cfg.env, video_dir, opts.video_episodes, deterministic, seed, opts.video_steps, algo=cfg.algo
        ):
            costs = v.episode_cost if isinstance(v.episode_cost, tuple) else (v.episode_cost,)
            print(
                f"wrote {v.path} ({v.frames} frames: return {v.episode_return:.3f}, "
                f"cost {'/'.join(f'{c:.0f}' for c in costs)})"
            )


if __name__ == "__main__":
    sys.exit(main())
