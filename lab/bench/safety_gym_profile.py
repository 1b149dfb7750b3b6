"""Where a navigation step's time goes in our pipeline: cProfile over one collector rollout of a
(freshly initialised) ppo_lag agent on a Safety-Gymnasium task, grouped by who spends it.

    python experiments/speed/safety_gym_profile.py [--task SafetyPointGoal1-v0] [--num-envs 8] [--steps-per-env 1000] [--top 0]

The rollout is what training does between updates: ``Collector.collect`` over ``--num-envs`` envs
(gymnasium's SyncVectorEnv, the default ``env.vector=sync``) for ``--steps-per-env`` steps each.
With the default 1000 (one navigation episode), every env ends one episode, so the rollout pays
one world rebuild per 1000 steps, as a long training run does; the first reset (the collector's
construction) is not profiled. The timer is this process's CPU time (user + system), so other
jobs on the machine do not inflate the figures; cProfile's own overhead does (it weighs on
Python-heavy parts most), so the total is slower than an unprofiled run.

Groups (CPU ms per env step; "of which" rows are parts of the row above):

- policy forward: ``Agent.act`` (the actor network and the action sample, observation normalizer
  included), called once per vector step for all envs;
- collector: ``Collector.collect`` minus the env's step and the policy (TensorDict bookkeeping,
  episode sums, the batch);
- our vector env and adapter: ``GymVecEnv.step`` and ``SafetyGymTask.step`` minus the package
  (tensor conversion, autoreset bookkeeping in gymnasium's SyncVectorEnv, the five-value step);
- world rebuild at reset: Safety-Gymnasium's ``Builder.reset`` (new layout, MJCF written and
  compiled by MuJoCo), of which the compile (``MjModel.from_xml_string``);
- the package's step: ``Builder.step``, of which MuJoCo physics (the ``mujoco._functions`` calls:
  ``mj_step`` per substep, the ``mj_forward`` its observation starts with), its pseudo-lidar, the
  check of every observation against its space (an ``assert ... contains`` in its ``obs()``), the
  rest of its observation (sensors, compass, flattening), its cost, its reward, and the rest of its
  Python (action, goal checks, info);
- MuJoCo name look-ups (``model.body(name)`` and the other ``mujoco._structs`` accessors), wherever
  they are made (mostly inside the observation, some in the reset): a cross-cutting row.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import time
from pathlib import Path

import torch

from cmdp_rl import Collector, make_env
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.policies import make_agent
from cmdp_rl.rollout.normalization import make_normalizers
from cmdp_rl.run.rng import seed_everything


def _outer(stats: pstats.Stats, match) -> float:
    """Cumulative time of the functions ``match`` accepts (a (file, line, name) key), counting only
    calls from functions it does not accept: a matched function called by another one (lidar's
    helpers, a Dict space checking its Box spaces) is not counted twice."""
    total = 0.0
    for key, (_, _, _, _, callers) in stats.stats.items():
        if match(key):
            total += sum(ct for caller, (_, _, _, ct) in callers.items() if not match(caller))
            if not callers:  # the profiled root
                total += stats.stats[key][3]
    return total


def _fn(file_end: str, *names: str):
    return lambda k: k[0].endswith(file_end) and k[2] in names


def _builtin(part: str, but: str = "\0"):
    return lambda k: k[0] == "~" and part in k[2] and but not in k[2]


def _called_from(stats: pstats.Stats, match, caller_match) -> float:
    """Time spent in calls of ``match``-ed functions made directly by ``caller_match``-ed ones."""
    return sum(
        ct
        for key, (_, _, _, _, callers) in stats.stats.items()
        if match(key)
        for caller, (_, _, _, ct) in callers.items()
        if caller_match(caller)
    )


def groups(stats: pstats.Stats) -> list[tuple[str, float]]:
    collect = _outer(stats, _fn("cmdp_rl/rollout/collector.py", "collect"))
    policy = _outer(stats, _fn("cmdp_rl/policies/agent.py", "act"))
    vec_step = _outer(stats, _fn("cmdp_rl/envs/vector.py", "step"))
    adapter = _outer(stats, _fn("cmdp_rl/envs/safety_gym/env.py", "step"))
    reset = _outer(stats, _fn("safety_gymnasium/builder.py", "reset"))
    compile_ = _outer(stats, _builtin("from_xml_string"))
    pkg_step = _outer(stats, _fn("safety_gymnasium/builder.py", "step"))
    physics_all = _outer(stats, _builtin("mujoco._functions."))
    # MuJoCo calls the world's build and reset make (mj_forward after a compile) belong to the reset.
    in_world = _fn("safety_gymnasium/world.py", "build", "reset", "rebuild")
    physics = physics_all - _called_from(stats, _builtin("mujoco._functions."), in_world)
    in_obs = _fn("safety_gymnasium/bases/base_task.py", "obs")
    obs = _outer(stats, in_obs)
    physics_in_obs = _called_from(stats, _builtin("mujoco._functions."), in_obs)  # its mj_forward
    lidar = _outer(
        stats, _fn("safety_gymnasium/bases/base_task.py", "_obs_lidar", "_obs_lidar_pseudo", "_obs_lidar_natural")
    )
    spaces = _outer(stats, lambda k: "gymnasium/spaces/" in k[0] and k[2] == "contains")
    lookups = _outer(stats, _builtin("mujoco._structs.", but="from_xml_string"))
    cost = _outer(stats, lambda k: "safety_gymnasium/" in k[0] and k[2] == "calculate_cost")
    reward = _outer(stats, lambda k: "safety_gymnasium/" in k[0] and k[2] == "calculate_reward")
    rest = pkg_step - physics - (obs - physics_in_obs) - cost - reward
    return [
        ("total (Collector.collect)", collect),
        ("policy forward (Agent.act)", policy),
        ("collector's own bookkeeping", collect - vec_step - policy),
        ("our vector env + adapter (GymVecEnv, SafetyGymTask, SyncVectorEnv)", vec_step - pkg_step - reset),
        ("  of which the five-value adapter (SafetyGymTask.step)", adapter - pkg_step),
        ("world rebuild at reset (Builder.reset)", reset),
        ("  of which the MJCF compile (MjModel.from_xml_string)", compile_),
        ("package step (Builder.step)", pkg_step),
        ("  of which MuJoCo physics (mj_step x substeps, mj_forward)", physics),
        ("  of which lidar (pseudo-lidar, per object group)", lidar),
        ("  of which the check of every observation (Space.contains)", spaces),
        ("  of which the rest of its observation (sensors, compass, flatten)", obs - physics_in_obs - lidar - spaces),
        ("  of which its cost (calculate_cost: hazard distances, contacts)", cost),
        ("  of which its reward (calculate_reward)", reward),
        ("  of which the rest of its Python (action, goal checks, info)", rest),
        ("MuJoCo name look-ups (model.body(name), ...; within the rows above)", lookups),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="SafetyPointGoal1-v0")
    parser.add_argument("--algo", default="ppo_lag")
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--steps-per-env", type=int, default=1000)
    parser.add_argument("--top", type=int, default=0, help="also print the N functions with the most own time")
    parser.add_argument("--save", default="outputs/safety_gym_profile.prof", help="the raw cProfile stats (pstats)")
    args = parser.parse_args()
    cfg = compose_config(
        [
            "env=safety_gym",
            f"env.task={args.task}",
            f"algo={args.algo}",
            f"env.num_envs={args.num_envs}",
            f"rollout_steps={args.steps_per_env}",
        ]
    )
    torch.set_num_threads(cfg.threads)
    seed_everything(cfg.seed)
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env, make_normalizers(cfg, env))
    collector = Collector(env, agent, cfg.rollout_steps, seed=cfg.seed)  # the first reset: not profiled
    load_before = os.getloadavg()
    prof = cProfile.Profile(time.process_time)
    wall = time.perf_counter()
    prof.runcall(collector.collect)
    wall = time.perf_counter() - wall
    load_after = os.getloadavg()
    env.close()
    Path(args.save).parent.mkdir(parents=True, exist_ok=True)
    prof.dump_stats(args.save)
    stats = pstats.Stats(prof)
    steps = args.num_envs * args.steps_per_env
    rows = groups(stats)
    total = rows[0][1]
    print(
        f"{args.task}, {args.algo} agent (untrained), {args.num_envs} envs x {args.steps_per_env} steps = {steps} "
        f"env steps, one collector rollout under cProfile; {os.cpu_count()} cores, load average (1, 5, 15 min) "
        f"before {tuple(round(x, 2) for x in load_before)}, after {tuple(round(x, 2) for x in load_after)}"
    )
    print(f"CPU {total:.2f} s ({steps / total:,.0f} steps/s profiled), wall {wall:.2f} s\n")
    width = max(len(r[0]) for r in rows)
    print(f"{'part':<{width}} | ms/step | share")
    print(f"{'-' * width}-|---------|------")
    for name, seconds in rows:
        print(f"{name:<{width}} | {1000 * seconds / steps:7.3f} | {seconds / total:5.1%}")
    if args.top:
        stats.sort_stats("tottime").print_stats(args.top)


if __name__ == "__main__":
    main()
