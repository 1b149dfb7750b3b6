"""The PPO-family update of every agent at once: ``PPO.update``'s steps with each agent's own
single-run algorithm object, and the minibatch loop written once (``algos/update_backend.py``)
on the stacked backend here.

Per iteration: torchrl's GAE (``advantages.TwinGAE``) on the whole ``[P N, T]`` batch (its
recursion runs along time, row by row); each agent's ``prepare`` on its own rows (J_c, the
multiplier, the policy advantage, normalised over its rows); the first agent's ``minibatch_step``
(the algorithm's surrogate and the critics' MSE, reduced per agent on ``[P, B, ...]``) through
``run_epochs`` with :class:`StackedAgents`; CUP's stage 2 likewise; each agent's ``finish``.
"""

from __future__ import annotations

from functools import partial
from typing import Any, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl import keys
from cmdp_rl.advantages import TwinGAE
from cmdp_rl.algos.base import TrainingDiverged
from cmdp_rl.algos.cup import HALF
from cmdp_rl.algos.update_backend import run_epochs
from cmdp_rl.config import RunConfig
from cmdp_rl.population.agent import PopulationAgent
from cmdp_rl.population.params import StackedAdam


class StackedAgents:
    """P agents' side of the shared minibatch loop (``algos/update_backend.Backend``): units
    ``[P, U, ...]``, each agent's permutations from its generator, per-agent means, the fused
    training pass, per-row clipping, ``StackedAdam``, and the KL mask."""

    def __init__(self, agent: PopulationAgent, algos: Sequence[Any], max_grad_norm: float) -> None:
        self.agent, self.max_grad_norm, P = agent, max_grad_norm, agent.num_agents
        device = agent.actor.flat.device
        self.rows = torch.arange(P, device=device).unsqueeze(1)
        # each algorithm's own coefficient: a regularised multiplier adds its tau to the configured one
        self.entropy_coef = torch.tensor([a.entropy_coef for a in algos], dtype=torch.float32, device=device)
        limits = [a.kl_limit for a in algos]
        self.kl_limit = None if limits[0] is None else torch.tensor(limits, dtype=torch.float32, device=device)

    def start(self) -> torch.Tensor:
        return torch.ones(self.agent.num_agents, dtype=torch.bool, device=self.rows.device)

    def any_active(self, active: torch.Tensor) -> bool:
        return self.kl_limit is None or bool(active.any().item())  # no limit: all, no host sync

    def units(self, data: dict) -> int:
        return next(iter(data.values())).shape[1]

    def shuffle(self, data: dict, active: torch.Tensor) -> dict:
        total = self.units(data)
        perm = torch.stack(
            [
                torch.randperm(total, generator=g, device=g.device) if on else torch.arange(total, device=g.device)
                for g, on in zip(self.agent.generators, active.tolist())
            ]
        )
        return {k: v[self.rows, perm] for k, v in data.items()}

    def minibatch(self, shuffled: dict, start: int, stop: int) -> dict:
        return {k: v[:, start:stop] for k, v in shuffled.items()}

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """The mean over each agent's rows: ``[P, B, ...]`` -> ``[P]``."""
        return x.reshape(self.agent.num_agents, -1).mean(1)

    def dist(self, mb: dict) -> Any:
        return self.agent.dist(mb[keys.OBS])

    def training_pass(self, mb: dict) -> tuple[Any, dict[str, torch.Tensor]]:
        dist, value, cost_value = self.agent.training_pass(mb[keys.OBS])
        return dist, {"reward": value, "cost": cost_value}

    def stop(self, kl: torch.Tensor, active: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        if self.kl_limit is None:  # None: every agent steps
            return active, None
        active = active & ~(kl > self.kl_limit)
        return active, active

    def step(self, loss: torch.Tensor, groups: list, stepping: torch.Tensor | None) -> None:
        # The per-agent losses summed: agents share no parameter, so each one's gradient is its own loss's.
        for opt, _ in groups:
            opt.zero_grad()
        loss.sum().backward()
        for _, stacked in groups:
            stacked.clip_grad_norm_(self.max_grad_norm)
        for opt, _ in groups:
            opt.step(stepping)

    def kept(self, stats: dict[str, torch.Tensor], evaluated: torch.Tensor) -> dict[str, torch.Tensor]:
        if self.kl_limit is None:  # every agent evaluates every minibatch
            return {k: v.detach() for k, v in stats.items()}
        return {k: torch.where(evaluated, v.detach(), 0.0) for k, v in stats.items()}

    def count(self, evaluated: torch.Tensor) -> torch.Tensor:
        return evaluated.to(torch.float32)


class PopulationPPO:
    """``algos`` are the agents' single-run algorithm objects (PPO or a subclass that keeps
    ``PPO.update``): each keeps its agent's J_c window, multiplier and schedule clock and gives its
    ``prepare``, ``minibatch_step`` (the first agent's, on the stacked backend) and ``finish``; the
    networks and the optimisers are here."""

    def __init__(
        self, cfgs: Sequence[RunConfig], algos: Sequence[Any], agent: PopulationAgent, envs_per_agent: int
    ) -> None:
        first = cfgs[0].algo
        self.cfg = first  # shared options: discounts, epochs, minibatches, clip, max_grad_norm
        self.algos = list(algos)
        self.agent = agent
        self.n = envs_per_agent
        self.gae = TwinGAE(first.gamma, first.cost_gamma, first.gae_lambda)
        self.backend = StackedAgents(agent, self.algos, first.max_grad_norm)
        rates = [a.learning_rates() for a in self.algos]
        self.actor_opt = StackedAdam(agent.actor.flat, [lr for lr, _ in rates])
        self.critic_opt = StackedAdam(agent.critics.flat, [lr for _, lr in rates])

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        """One iteration for every agent on the ``[P N, T]`` batch; each agent's logged statistics."""
        cfg, agent, algo = self.cfg, self.agent, self.algos[0]
        if cfg.anneal_lr:  # PPO.update's schedule, per agent
            rates = torch.tensor([a.learning_rates() for a in self.algos], dtype=torch.float64)
            self.actor_opt.lr, self.critic_opt.lr = rates[:, 0].clone(), rates[:, 1].clone()
        self.gae(batch, agent)  # along time, row by row: the whole batch at once
        advs = [a.prepare(batch[i * self.n : (i + 1) * self.n]) for i, a in enumerate(self.algos)]
        batch.set(keys.POLICY_ADVANTAGE, torch.cat(advs))
        data = {k: self._units(batch.get(k)) for k in algo._update_keys(batch)}  # [P, N T, ...]
        groups = [(self.actor_opt, agent.actor), (self.critic_opt, agent.critics)]
        step = partial(algo.minibatch_step, self.backend, groups)
        sums, counts = run_epochs(self.backend, data, cfg.num_minibatches, cfg.update_epochs, step)
        means = {k: v / counts for k, v in sums.items()}  # each agent's mean over its minibatches
        if hasattr(algo, "projection_loss"):  # CUP's second stage (algos/cup.py)
            sums, counts = self._project(batch)
            means.update({k: v / counts for k, v in sums.items()})
        values = torch.stack(list(means.values())).tolist()  # [stats, P]: one host sync
        out = []
        for i, a in enumerate(self.algos):
            try:
                out.append(a.finish({k: values[s][i] for s, k in enumerate(means)}))
            except TrainingDiverged as exc:
                raise TrainingDiverged(f"agent {i}: {exc}") from exc
        for name, stacked in (("actor", agent.actor), ("critics", agent.critics)):
            bad = (~torch.isfinite(stacked.flat).all(1)).nonzero().flatten().tolist()
            if bad:
                raise TrainingDiverged(f"agent {bad[0]}: a parameter of the {name} is not finite after the update")
        return out

    def _units(self, x: torch.Tensor) -> torch.Tensor:
        return x.reshape(self.agent.num_agents, -1, *x.shape[2:])

    def _project(self, batch: TensorDictBase) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """CUP's stage 2 (``CUP.project``): each agent's ``projection_inputs`` on its rows,
        ``pi_{k+1/2}`` as stage 1 left each actor, a fresh Adam at each agent's stage-1 rate,
        ``CUP.projection_step`` with each agent's ``nu`` weight."""
        agent, algo = self.agent, self.algos[0]
        rows = [a.projection_inputs(batch[i * self.n : (i + 1) * self.n]) for i, a in enumerate(self.algos)]
        units = {k: self._units(torch.cat([r[k] for r in rows])) for k in rows[0]}
        with torch.no_grad():  # pi_{k+1/2}: each actor as stage 1 left it
            units.update({(HALF, k): v for k, v in agent.params(units[keys.OBS]).items()})
        coef = [a.projection_coef() for a in self.algos]
        nu_coef = torch.tensor(coef, dtype=torch.float32, device=self.backend.rows.device).view(-1, 1, 1)
        opt = StackedAdam(agent.actor.flat, self.actor_opt.lr.tolist())
        step = partial(algo.projection_step, self.backend, [(opt, agent.actor)], nu_coef)
        return run_epochs(self.backend, units, self.cfg.num_minibatches, self.cfg.projection_epochs, step)

    def _pairs(self) -> list[tuple[str, Any, StackedAdam, str]]:
        return [
            ("actor", self.agent.actor, self.actor_opt, "actor_opt"),
            ("critics", self.agent.critics, self.critic_opt, "critic_opt"),
        ]

    @torch.no_grad()
    def unstack_agents(self) -> None:
        """Each agent's networks, and its Adam moments through its optimiser's ``load_state_dict``,
        into its single-run algorithm object, whose ``state_dict`` is then its single run's (what a
        checkpoint holds per agent)."""
        for i, algo in enumerate(self.algos):
            for name, stacked, adam, opt_name in self._pairs():
                opt, saved = getattr(algo, opt_name), getattr(algo, opt_name).state_dict()
                params, m, v = (stacked.row(t, i) for t in (stacked.flat, adam.exp_avg, adam.exp_avg_sq))
                step = adam.steps[i].to(torch.float32)
                for k, (n, p) in enumerate(getattr(algo.agent, name).named_parameters()):
                    p.copy_(params[n])
                    saved["state"][k] = {"step": step.clone(), "exp_avg": m[n].clone(), "exp_avg_sq": v[n].clone()}
                opt.load_state_dict(saved)

    @torch.no_grad()
    def stack_agents(self) -> None:
        """The inverse of :meth:`unstack_agents`: after each agent's algorithm object loaded its
        state (a resume), its networks and Adam moments (no step yet: zero) into the stacked ones."""
        for i, algo in enumerate(self.algos):
            for name, stacked, adam, opt_name in self._pairs():
                saved = getattr(algo, opt_name).state_dict()["state"]
                rows = [stacked.row(t, i) for t in (stacked.flat, adam.exp_avg, adam.exp_avg_sq)]
                adam.steps[i] = 0.0
                for k, (n, p) in enumerate(getattr(algo.agent, name).named_parameters()):
                    state = saved.get(k, {})
                    for row, value in zip(rows, (p, state.get("exp_avg"), state.get("exp_avg_sq"))):
                        row[n].zero_() if value is None else row[n].copy_(value)
                    adam.steps[i] = float(state.get("step", 0.0))


__all__ = ["PopulationPPO"]
