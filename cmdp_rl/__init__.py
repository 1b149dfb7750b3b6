"""cmdp_rl: constrained reinforcement learning on TorchRL.

``import cmdp_rl`` registers ``cmdp_rl/Reach1D-v0`` with gymnasium and exposes the pieces
``train.py`` is built from, for a user's own script::

    cfg = cmdp_rl.RunConfig()                  # or cmdp_rl.load_config({...})
    env = cmdp_rl.make_env(cfg.env)
    agent = cmdp_rl.make_agent(cfg.policy, env, algo=cfg.algo)  # the agent the algorithm trains
    algo = cmdp_rl.make_algo(cfg.algo, agent)
    collector = cmdp_rl.Collector(env, agent, cfg.rollout_steps, seed=0)
    stats = algo.update(collector.collect())

and acts with what a finished run deployed::

    policy = cmdp_rl.load("outputs/<date>/<time>_ppo_lag_reach1d_s0")
    action, state = policy.predict(obs)                        # then predict(obs, state, episode_start=done)
"""

from pathlib import Path as _Path
from typing import Any as _Any
from typing import Callable as _Callable
from typing import Sequence as _Sequence

import gymnasium as _gym

from cmdp_rl.algos import TrainingDiverged, make_algo
from cmdp_rl.algos.ppo import PPO
from cmdp_rl.algos.ppo_lag import PenaltyPPO, PPOLagrangian
from cmdp_rl.config.registry import register
from cmdp_rl.config.run_config import ConfigError, RunConfig, load_config, validate
from cmdp_rl.envs import REACH1D_ID, GymVecEnv, Reach1D, VecEnv, make_env
from cmdp_rl.policies import Agent, make_agent
from cmdp_rl.population.spec import Population
from cmdp_rl.population.training import train_population
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import Collector, finished_episodes
from cmdp_rl.run.evaluation import evaluate
from cmdp_rl.run.loop import Observer
from cmdp_rl.run.rundir import load
from cmdp_rl.run.trainer import train as train_run

__version__ = "0.1.0"


def train(
    cfg: RunConfig | Population,
    out_dir: str | _Path | None = None,
    echo: _Callable[[str], None] = print,
    observers: _Sequence[Observer] = (),
) -> dict[str, _Any]:
    """Train a run (``cfg`` a :class:`RunConfig`: ``run.trainer.train``) or a population (``cfg`` a
    ``population.Population``, from ``population.population(raw)`` or ``population.resume.resume_population(dir)``:
    ``population.training.train_population``, its P agents each into a run directory ``out_dir/agents/<k>_<values>/``
    as its single run writes one). Returns a run's evaluation summary, or the population's ``population.json``.
    ``observers`` read each iteration's rows (``run.loop.Observer``)."""
    if isinstance(cfg, Population):
        if out_dir is None:
            raise ValueError("train: out_dir is required for a population")
        return train_population(cfg, _Path(out_dir), echo, observers)
    return train_run(cfg, out_dir, echo, observers)


if REACH1D_ID not in _gym.registry:
    _gym.register(id=REACH1D_ID, entry_point="cmdp_rl.envs.reach1d.env:Reach1D")

__all__ = [
    "Agent",
    "Collector",
    "ConfigError",
    "GymVecEnv",
    "PPO",
    "PPOLagrangian",
    "PenaltyPPO",
    "REACH1D_ID",
    "Reach1D",
    "RunConfig",
    "TrainingDiverged",
    "VecEnv",
    "evaluate",
    "finished_episodes",
    "keys",
    "load",
    "load_config",
    "make_agent",
    "make_algo",
    "make_env",
    "register",
    "train",
    "validate",
]
