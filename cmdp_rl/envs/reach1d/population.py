"""Reach1D's envs of P agents as one batched env (the ``population_env`` hook of its options, for
``cmdp_rl/population/``): agent i owns envs ``[i N, (i + 1) N)``. :class:`PopulationReach1D` is
``TorchReach1D`` on ``P N`` envs whose per-agent options (``obs_noise``, ``wall_x``, ``goal``,
``start``) are float64 tensors ``[P N]``, the same arithmetic elementwise, and whose noise
(:class:`PopulationNoise`) gives each agent its single run's draws: so each agent's envs step exactly
as its single run's ``TorchReach1D`` does (an agent with a fixed start draws no uniform at a reset).
"""

from __future__ import annotations

from typing import Any, Sequence

import torch

from cmdp_rl.envs.reach1d.batched import TorchReach1D


class PopulationNoise:
    """A noise source (:class:`~cmdp_rl.envs.reach1d.batched.TorchNoise`'s methods) for P agents of N
    envs each: agent i's draws come from its own generator, N at every call (as ``TorchNoise`` draws
    for all its envs); :meth:`uniform` draws only for the agents in ``agents``."""

    def __init__(self, num_agents: int, envs_per_agent: int, device: torch.device) -> None:
        self.num_agents, self.n, self.device = num_agents, envs_per_agent, device
        self.generators = [torch.Generator(device=device) for _ in range(num_agents)]
        # The agents that draw (None: all): while some agents' envs restart between steps
        # (PopulationReach1D.reset_rows) only those agents' single runs draw; the others' rows get 0.
        self.drawing: list[int] | None = None

    def _agents(self, agents: Sequence[int] | None) -> list[int]:
        chosen = range(self.num_agents) if agents is None else agents
        return [i for i in chosen if self.drawing is None or i in self.drawing]

    def seed_agents(self, seeds: Sequence[int]) -> None:
        for g, s in zip(self.generators, seeds):
            g.manual_seed(int(s))

    def seed(self, seed: int) -> None:
        raise ValueError("PopulationNoise: each agent has its own seed (seed_agents)")

    def _draw(self, sample: Any, agents: Sequence[int] | None) -> torch.Tensor:
        out = torch.zeros(self.num_agents, self.n, dtype=torch.float64, device=self.device)
        for i in self._agents(agents):
            out[i] = sample(self.n, dtype=torch.float64, device=self.device, generator=self.generators[i])
        return out.reshape(-1)

    def normal(self, where: torch.Tensor | None) -> torch.Tensor:
        return self._draw(torch.randn, None)

    def uniform(self, where: torch.Tensor | None, agents: Sequence[int] | None = None) -> torch.Tensor:
        return self._draw(torch.rand, agents)

    def state_dict(self) -> dict[str, Any]:
        return {"generators": [g.get_state() for g in self.generators]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for g, s in zip(self.generators, state["generators"]):
            g.set_state(s)


class PopulationReach1D(TorchReach1D):
    """P agents' Reach1D envs, N each, in one batched env. ``env_cfgs``: each agent's
    ``Reach1DConfig`` (shared options taken from the first; per-agent ones from each)."""

    def __init__(
        self, env_cfgs: Sequence[Any], envs_per_agent: int, stagger: bool, device: str | torch.device = "cpu"
    ) -> None:
        first = env_cfgs[0]
        p, n = len(env_cfgs), envs_per_agent
        dev = torch.device(device)
        noise = PopulationNoise(p, n, dev)
        kwargs = {**first.env_kwargs(), "probe": False}
        super().__init__(p * n, **kwargs, stagger=stagger, device=dev, noise=noise)
        self.num_agents, self.envs_per_agent = p, n

        def per_env(values: list[float]) -> torch.Tensor:
            return torch.tensor(values, dtype=torch.float64, device=dev).repeat_interleave(n)

        for name in ("obs_noise", "wall_x", "goal"):
            setattr(self, name, per_env([float(getattr(c, name)) for c in env_cfgs]))
        self._goal32 = self.goal.to(torch.float32)
        starts = [c.start if isinstance(c.start, list) else [c.start, c.start] for c in env_cfgs]
        self.start_lo = per_env([float(s[0]) for s in starts])
        self.start_hi = per_env([float(s[1]) for s in starts])
        self.range_agents = [i for i, c in enumerate(env_cfgs) if isinstance(c.start, list)]
        is_range = torch.zeros(p, dtype=torch.bool, device=dev)
        is_range[self.range_agents] = True
        self.start_is_range = is_range.repeat_interleave(n)

    def seed_agents(self, seeds: Sequence[int]) -> None:
        self.noise.seed_agents(seeds)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        # Only the agents with a restarted env draw, as their single runs' envs do.
        self.noise.drawing = torch.nonzero(rows.view(self.num_agents, -1).any(1)).view(-1).tolist()
        try:
            return super().reset_rows(rows)
        finally:
            self.noise.drawing = None

    def _start_x(self, where: torch.Tensor | None) -> torch.Tensor:
        fixed = self.start_lo
        if not self.range_agents:
            return fixed.clone()
        # numpy's Generator.uniform(lo, hi) is lo + (hi - lo) * u, as the single env computes it.
        drawn = self.start_lo + (self.start_hi - self.start_lo) * self.noise.uniform(where, self.range_agents)
        return torch.where(self.start_is_range, drawn, fixed)
