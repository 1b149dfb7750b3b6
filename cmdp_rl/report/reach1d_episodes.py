"""Replaying Reach1D episodes with what the agent could not see, and drawing them: the true position lives in
the env's ``info`` and never reaches a batch, so replay steps one plain Reach1D away from the collector."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from cmdp_rl.envs import Reach1D
from cmdp_rl.envs.reach1d.task import Reach1DConfig
from cmdp_rl.policies.agent import Agent
from cmdp_rl.report.plot import pyplot, save_figure
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import PolicyMemory


@dataclass
class Reach1DEpisode:
    """One episode, step 0 being the reset: ``true_x[t]`` and ``reading[t]`` after ``t`` steps;
    ``cost[t]``, ``reward[t]``, ``action[t]`` of step ``t + 1``."""

    true_x: list[float] = field(default_factory=list)
    reading: list[float] = field(default_factory=list)
    action: list[float] = field(default_factory=list)
    reward: list[float] = field(default_factory=list)
    cost: list[float] = field(default_factory=list)
    terminated: bool = False

    @property
    def episode_return(self) -> float:
        return float(sum(self.reward))

    @property
    def episode_cost(self) -> float:
        return float(sum(self.cost))


@torch.no_grad()
def record_reach1d(
    agent: Agent, env_cfg: Reach1DConfig, episodes: int, deterministic: bool = True, seed: int = 0
) -> list[Reach1DEpisode]:
    """``episodes`` episodes of ``agent`` on one Reach1D (reset with ``seed`` once), with the true positions."""
    env = Reach1D(**env_cfg.env_kwargs())
    memory = PolicyMemory(agent, 1, env.action_space, torch.device("cpu"))
    out: list[Reach1DEpisode] = []
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        obs, info = env.reset(seed=seed)
        for _ in range(episodes):
            ep = Reach1DEpisode(true_x=[info["true_x"]], reading=[float(obs[0])])
            is_init, carried = True, memory.start()
            while True:
                wrote = agent.act(
                    {**carried, keys.OBS: torch.as_tensor(obs).unsqueeze(0), keys.IS_INIT: torch.tensor([[is_init]])},
                    deterministic,
                )
                action = wrote[keys.ACTION][0].numpy().astype(env.action_space.dtype)  # as GymVecEnv sends it
                obs, reward, terminated, truncated, info = env.step(action)
                # as in the collector: the policy's next state, previous action and cost
                _, carried = memory.step(wrote, torch.tensor([[float(info["cost"])]]), torch.tensor([[False]]))
                ep.action.append(float(action[0]))
                ep.reward.append(float(reward))
                ep.cost.append(float(info["cost"]))
                ep.true_x.append(float(info["true_x"]))
                ep.reading.append(float(obs[0]))
                is_init = False
                if terminated or truncated:
                    ep.terminated = bool(terminated)
                    break
            out.append(ep)
            obs, info = env.reset()
    env.close()
    return out


def plot_reach1d(episodes: list[Reach1DEpisode], env_cfg: Reach1DConfig, path: str | Path, title: str = "") -> Path:
    """A panel per episode: true position and reading over time, the wall, the goal (its 0.02 band), crossings."""
    plt = pyplot()
    n = len(episodes)
    fig, axes = plt.subplots(n, 1, figsize=(9.5, 2.4 * n), sharex=True, squeeze=False)
    for i, (ax, ep) in enumerate(zip(axes[:, 0], episodes)):
        t = np.arange(len(ep.true_x))
        ax.axhline(env_cfg.wall_x, color="0.3", lw=3, alpha=0.6, label=f"wall ({env_cfg.wall})")
        ax.axhspan(env_cfg.goal - 0.02, env_cfg.goal + 0.02, color="tab:green", alpha=0.15)
        ax.axhline(env_cfg.goal, color="tab:green", ls="--", label="goal")
        ax.plot(t, ep.reading, ".", color="tab:orange", ms=4, alpha=0.8, label="reading (observed)")
        ax.plot(t, ep.true_x, "-", color="tab:blue", lw=1.5, label="true x")
        hits = [s + 1 for s, c in enumerate(ep.cost) if c > 0]
        if hits:
            ax.plot(hits, [ep.true_x[s] for s in hits], "x", color="red", ms=8, mew=2, label=f"collision ({len(hits)})")
        end = "goal reached" if ep.terminated else "time limit"
        ax.set_title(
            f"episode {i + 1}: return {ep.episode_return:.3f}, cost {ep.episode_cost:.0f}, {len(ep.cost)} steps, {end}",
            fontsize=9,
        )
        ax.set_ylabel("position")
        ax.set_ylim(-0.02, 1.02)
        if i == 0:
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    axes[-1, 0].set_xlabel("step")
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)
