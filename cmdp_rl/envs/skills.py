"""``env=skills``: a point on a line reaches a goal with two skills that differ in cost, a hybrid action space (the
skill and its parameter; docs/multi_agent_and_hybrid.md gives the returns of each policy).

The point starts at ``x = 0`` and must reach ``x >= goal`` within ``max_steps``. ``walk``: ``x += walk_step * a``, free;
``dash``: ``x -= dash_step * a``, cost 1 (its parameter points the other way, so the best parameter depends on the
skill); ``x`` stays in ``[0, 1]``. Reward: the progress, minus ``step_penalty`` a step, plus ``goal_reward`` on arrival.
Observation ``[x, t / max_steps]``; ``hold = k > 1``: :class:`~cmdp_rl.envs.hold.HeldSkill`."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import gymnasium as gym
import numpy as np
import torch

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import PositiveFloat, PositiveInt, finite, options
from cmdp_rl.envs.hold import HeldSkill
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.vector import Step, VecEnv

SKILLS = ("walk", "dash")


@options
class SkillsConfig(EnvOptions):
    """``env=skills``: options checked before anything is built (module docstring)."""

    name: str = "skills"
    backend: Literal["torch"] = "torch"
    num_envs: PositiveInt = 16
    max_steps: PositiveInt = 20
    goal: Annotated[float, finite(gt=0, le=1)] = 0.92
    walk_step: PositiveFloat = 0.1
    dash_step: PositiveFloat = 0.35
    step_penalty: Annotated[float, finite(ge=0)] = 0.1
    goal_reward: Annotated[float, finite(ge=0)] = 1.0
    hold: PositiveInt = 1  # the high-level policy picks a skill every `hold` steps (envs/hold.py)
    termination_metric: ClassVar[str] = "goal_reached"


class TorchSkills(VecEnv):
    """N envs of the module docstring in tensors; actions ``[N, 2]``: skill index, parameter."""

    _cost_names = ("dash",)
    saved = ("x", "t")  # positions and step counts: VecEnv saves and restores them

    def __init__(self, cfg: SkillsConfig, num_envs: int, device: str | torch.device = "cpu") -> None:
        self.cfg = cfg
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.obs_dim, self.action_dim = 2, 2
        self.action_low = torch.tensor([0.0, -1.0], device=self.device)
        self.action_high = torch.tensor([len(SKILLS) - 1.0, 1.0], device=self.device)
        self.reset()

    @property
    def action_space(self) -> gym.Space:
        return gym.spaces.Tuple(
            (gym.spaces.Discrete(len(SKILLS)), gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32))
        )

    def _obs(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return torch.stack([x, t.float() / self.cfg.max_steps], dim=-1)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        # Deterministic dynamics and start: the seed has nothing to draw.
        self.x = torch.zeros(self.num_envs, device=self.device)
        self.t = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)
        return self._obs(self.x, self.t)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        self.x = self.x.masked_fill(rows, 0.0)
        self.t = self.t.masked_fill(rows, 0)
        return self._obs(self.x[rows], self.t[rows])

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        cfg = self.cfg
        skill = action[:, 0].round().long()
        if bool(((skill < 0) | (skill >= len(SKILLS))).any()):
            raise ValueError(f"skills: the skill index must be in 0..{len(SKILLS) - 1}, got {action[:, 0].tolist()}")
        a = action[:, 1].clamp(-1.0, 1.0)
        dash = skill == 1
        dx = torch.where(dash, -cfg.dash_step * a, cfg.walk_step * a)
        x = (self.x + dx).clamp(0.0, 1.0)
        t = self.t + 1
        reached = x >= cfg.goal
        reward = (x - self.x) - cfg.step_penalty + cfg.goal_reward * reached.float()
        truncated = ~reached & (t >= cfg.max_steps)
        done = reached | truncated
        next_obs = self._obs(x, t)
        self.x = x.masked_fill(done, 0.0)
        self.t = t.masked_fill(done, 0)
        return Step(
            next_obs=next_obs,
            reward=reward.unsqueeze(-1),
            cost=dash.float().unsqueeze(-1),
            terminated=reached.unsqueeze(-1),
            truncated=truncated.unsqueeze(-1),
            obs=self._obs(self.x, self.t),
        )


def make_skills(cfg: SkillsConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    env = TorchSkills(cfg, num_envs, device)
    return env if cfg.hold == 1 else HeldSkill(env, cfg.hold)


register("env", "skills", SkillsConfig, make_skills)
