"""Reach1D as one tensor program over N environments: the batched backend (``env.backend=torch``).

The state is a float64 tensor ``x[N]``, so every step does the gymnasium :class:`Reach1D`'s float64
arithmetic elementwise and, fed the same noise draws, gives the same observations, rewards, costs,
flags and positions to the last bit (``tests/test_reach1d_torch.py``), episode resets included
(SAME_STEP, in the gymnasium env's draw order). Actions are cast to float32 and clipped to the
float32 bound first, as the gymnasium path does, so the seed's float64 wall edge (``env.py``) is out
of reach here too. No Python loop over envs and no host sync: CPU or CUDA alike.
"""

from __future__ import annotations

from typing import Any

import torch

from cmdp_rl.envs.reach1d.env import WALL_MODES
from cmdp_rl.envs.vector import Step, VecEnv


class TorchNoise:
    """The noise source of the N envs: standard normal and standard uniform [0, 1) draws, float64
    ``[N]``; ``where`` (bool ``[N]``, None for all) says which envs consume this call's draw, the
    others' entries being ignored. Per env, draws come in the gymnasium env's order: at a step, one
    normal (the reading); at a reset, one uniform if the start is a range, then one normal. This one,
    the default, is a ``torch.Generator`` on the env's device (seeded by ``reset(seed)``) drawing for
    all N envs at every call (cheaper than gathering the envs that need a draw, and sync-free on
    CUDA); a test injects a source with the same methods that replays another generator's draws."""

    def __init__(self, num_envs: int, device: torch.device) -> None:
        self.num_envs = num_envs
        self.device = device
        self.generator = torch.Generator(device=device)

    def seed(self, seed: int) -> None:
        self.generator.manual_seed(seed)

    def state_dict(self) -> dict[str, Any]:
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.generator.set_state(state["generator"])

    def normal(self, where: torch.Tensor | None) -> torch.Tensor:
        return torch.randn(self.num_envs, dtype=torch.float64, device=self.device, generator=self.generator)

    def uniform(self, where: torch.Tensor | None) -> torch.Tensor:
        return torch.rand(self.num_envs, dtype=torch.float64, device=self.device, generator=self.generator)


class TorchReach1D(VecEnv):
    """N Reach1D envs in tensors; the options and their meaning are :class:`~cmdp_rl.envs.Reach1D`'s.

    ``stagger``: at ``reset``, each env's step counter starts at a random value in ``[0, max_steps)``,
    so the envs' episodes end at different steps, as in massively parallel PPO (Rudin et al., 2022,
    "Learning to Walk in Minutes Using Massively Parallel Deep RL"). Without it, N envs started
    together all time out at once: with rollouts shorter than an episode, most batches hold no
    finished episode (no new cost estimate for the multiplier) and cover one phase of the episode
    only. Off by default (the gymnasium env's behaviour); evaluation always runs without it.

    After each step, ``final_x`` holds every env's true position after the move (before any reset,
    gymnasium's ``info["true_x"]``) and ``x`` the position the next step starts from.
    """

    saved = ("x", "final_x", "steps", "last_probe", "noise")

    def __init__(
        self,
        num_envs: int,
        obs_noise: float = 0.02,
        wall_x: float = 0.5,
        max_steps: int = 100,
        goal: float = 0.9,
        wall: str = "block",
        start: float | tuple[float, float] | list[float] = 0.1,
        probe: bool = False,
        stagger: bool = False,
        device: str | torch.device = "cpu",
        noise: Any = None,
    ) -> None:
        if wall not in WALL_MODES:
            raise ValueError(f"env.wall must be one of {WALL_MODES}, got {wall!r}")
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.obs_noise = float(obs_noise)
        self.wall_x = float(wall_x)
        self.max_steps = int(max_steps)
        self.goal = float(goal)
        self.block = wall == "block"
        self.start = tuple(float(s) for s in start) if isinstance(start, (tuple, list)) else float(start)
        self.probe = probe
        self.stagger = stagger
        self.noise = noise if noise is not None else TorchNoise(num_envs, self.device)
        self.action_dim = 2 if probe else 1
        self.obs_dim = 3 if probe else 2
        # The gymnasium env's float32 bounds: a clipped action equals np.clip's there.
        low, high = ([-0.1, -1.0], [0.1, 1.0]) if probe else ([-0.1], [0.1])
        self.action_low = torch.tensor(low, dtype=torch.float32, device=self.device)
        self.action_high = torch.tensor(high, dtype=torch.float32, device=self.device)
        f64 = dict(dtype=torch.float64, device=self.device)
        self.x = torch.zeros(num_envs, **f64)
        self.final_x = torch.zeros(num_envs, **f64)
        self.steps = torch.zeros(num_envs, dtype=torch.int64, device=self.device)
        self.last_probe = torch.full((num_envs,), -1.0, **f64)
        self._goal32 = torch.full((num_envs,), self.goal, dtype=torch.float32, device=self.device)

    def _start_x(self, where: torch.Tensor | None) -> torch.Tensor:
        if isinstance(self.start, tuple):
            lo, hi = self.start
            # numpy's Generator.uniform(lo, hi) is lo + (hi - lo) * u, u a standard uniform.
            return lo + (hi - lo) * self.noise.uniform(where)
        return torch.full((self.num_envs,), self.start, dtype=torch.float64, device=self.device)

    def _reading(self, x: torch.Tensor, std: float | torch.Tensor, where: torch.Tensor | None) -> torch.Tensor:
        # numpy's Generator.normal(0, std) is 0 + std * z: the same float64 product.
        return (x + std * self.noise.normal(where)).clamp_(0.0, 1.0)

    def _obs(self, reading: torch.Tensor, last_probe: torch.Tensor) -> torch.Tensor:
        cols = [reading.to(torch.float32), self._goal32]
        if self.probe:
            cols.append(last_probe.to(torch.float32))
        return torch.stack(cols, dim=-1)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        if seed is not None:
            self.noise.seed(seed)
        self.x = self._start_x(None)
        self.final_x = self.x.clone()
        self.last_probe.fill_(-1.0)
        obs = self._obs(self._reading(self.x, self.obs_noise, None), self.last_probe)
        if self.stagger:  # drawn after the gymnasium env's draws, which stay in their order
            self.steps = (self.noise.uniform(None) * self.max_steps).long().clamp_(max=self.max_steps - 1)
        else:
            self.steps.zero_()
        return obs

    def _restart(
        self, rows: torch.Tensor, x: torch.Tensor, steps: torch.Tensor, last_probe: torch.Tensor
    ) -> torch.Tensor:
        """New episodes in ``rows`` over the state (x, steps, last_probe), with the gymnasium env's
        draws in its order; sets the state and returns every row's observation of it (the restarted
        rows' first ones). step's auto-reset and reset_rows both start episodes through it."""
        x0 = self._start_x(rows)
        reading0 = self._reading(x0, self.obs_noise, rows)
        self.x = torch.where(rows, x0, x)
        self.steps = steps.masked_fill(rows, 0)
        self.last_probe = last_probe.masked_fill(rows, -1.0)
        return self._obs(reading0, self.last_probe)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        return self._restart(rows, self.x, self.steps, self.last_probe)[rows]

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        act = action.to(device=self.device, dtype=torch.float32)
        act = torch.maximum(torch.minimum(act, self.action_high), self.action_low)
        move = act[:, 0].to(torch.float64)
        std: float | torch.Tensor = self.obs_noise
        if self.probe:
            probing = act[:, 1] > 0.0
            move = move.masked_fill(probing, 0.0)  # a probe makes no motion
            # float64 like every scalar here (torch.where of two Python floats would give float32).
            std = torch.full_like(self.x, self.obs_noise).masked_fill_(probing, self.obs_noise / 2)
        prev = self.x
        proposed = (prev + move).clamp_(0.0, 1.0)
        # Strict test, as the seed: landing exactly on the wall is not a crossing.
        crossed = (prev - self.wall_x) * (proposed - self.wall_x) < 0
        x = torch.where(crossed, prev, proposed) if self.block else proposed
        dist = (self.goal - x).abs()
        reward = (self.goal - prev).abs() - dist
        terminated = dist < 0.02
        reward = torch.where(terminated, reward + 1.0, reward)
        steps = self.steps + 1
        truncated = steps >= self.max_steps
        reading = self._reading(x, std, None)
        last_probe = torch.where(probing, reading, self.last_probe) if self.probe else self.last_probe
        next_obs = self._obs(reading, last_probe)

        # Auto-reset the envs whose episode ended, in the gymnasium env's draw order.
        done = terminated | truncated
        self.final_x = x
        obs = torch.where(done.unsqueeze(-1), self._restart(done, x, steps, last_probe), next_obs)
        return Step(
            next_obs=next_obs,
            reward=reward.to(torch.float32).unsqueeze(-1),
            cost=crossed.to(torch.float32).unsqueeze(-1),
            terminated=terminated.unsqueeze(-1),
            truncated=truncated.unsqueeze(-1),
            obs=obs,
        )
