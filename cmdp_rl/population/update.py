"""The agents' update. :class:`PopulationPPO`, the PPO family's, is every agent's at once: the
iteration and its minibatch loop written once (``algos/update_backend.iterate``), each agent's own
single-run algorithm object around it, on the stacked backend here: units ``[P, U, ...]``, each
agent's permutations from its generator, per-agent means, the fused training pass, per-row clipping,
``StackedAdam``, the KL mask. :class:`AgentUpdates`, any other on-policy algorithm's (the
trust-region family), is each agent's single-run update on its own rows, one after another.
"""

from __future__ import annotations

from typing import Any, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl import keys
from cmdp_rl.algos.base import TrainingDiverged
from cmdp_rl.algos.update_backend import iterate
from cmdp_rl.population.agent import PopulationAgent
from cmdp_rl.population.params import StackedAdam


class PopulationPPO:
    """P agents' side of the shared update (``algos/update_backend.Backend``). ``algos`` are the
    agents' single-run algorithm objects (PPO or a subclass that keeps ``PPO.update``): each keeps
    its agent's J_c window, multiplier and schedule clock; the networks and optimisers are here."""

    def __init__(self, agent: PopulationAgent, algos: Sequence[Any]) -> None:
        self.agent, self.algos, P = agent, list(algos), agent.num_agents
        self.max_grad_norm = self.algos[0].cfg.max_grad_norm  # shared, as every shape and schedule
        device = agent.actor.flat.device
        self.rows = torch.arange(P, device=device).unsqueeze(1)
        # each algorithm's own coefficient: a regularised multiplier adds its tau to the configured one
        self.entropy_coef = torch.tensor([a.entropy_coef for a in algos], dtype=torch.float32, device=device)
        limits = [a.kl_limit for a in algos]
        self.kl_limit = None if limits[0] is None else torch.tensor(limits, dtype=torch.float32, device=device)
        rates = [a.learning_rates() for a in self.algos]
        self.actor_opt = StackedAdam(agent.actor.flat, [lr for lr, _ in rates])
        self.critic_opt = StackedAdam(agent.critics.flat, [lr for _, lr in rates])

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        """One iteration for every agent on the ``[P N, T]`` batch; each agent's logged statistics."""
        return iterate(self.algos, batch, self)

    # --- around the epochs ----------------------------------------------------------------------
    def set_rates(self, algos: Sequence[Any]) -> None:
        rates = torch.tensor([a.learning_rates() for a in algos], dtype=torch.float64)
        self.actor_opt.lr, self.critic_opt.lr = rates[:, 0].clone(), rates[:, 1].clone()

    def groups(self, algos: Sequence[Any]) -> list:
        return [(self.actor_opt, self.agent.actor), (self.critic_opt, self.agent.critics)]

    def fresh_actor_groups(self, algos: Sequence[Any]) -> list:
        return [(StackedAdam(self.agent.actor.flat, self.actor_opt.lr.tolist()), self.agent.actor)]

    def training_units(self, data: dict) -> dict:
        return {k: v.reshape(self.agent.num_agents, -1, *v.shape[2:]) for k, v in data.items()}

    def actor_params(self, units: dict) -> dict[str, torch.Tensor]:
        return self.agent.params(units[keys.OBS])

    def per_member(self, values: Sequence[float]) -> torch.Tensor:
        return torch.tensor(values, dtype=torch.float32, device=self.rows.device).view(-1, 1, 1)

    def check_finite(self) -> None:
        for name, stacked in (("actor", self.agent.actor), ("critics", self.agent.critics)):
            bad = (~torch.isfinite(stacked.flat).all(1)).nonzero().flatten().tolist()
            if bad:
                raise TrainingDiverged(f"agent {bad[0]}: a parameter of the {name} is not finite after the update")

    # --- the epochs -----------------------------------------------------------------------------
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
    def copy_actors(self, to_modules: bool) -> None:
        """The stacked actors' rows into each agent's single-run actor (``to_modules``), or back."""
        for i, algo in enumerate(self.algos):
            row = self.agent.actor.row(self.agent.actor.flat, i)
            for n, p in algo.agent.actor.named_parameters():
                p.copy_(row[n]) if to_modules else row[n].copy_(p)

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


class AgentUpdates:
    """Each agent's own single-run update (``algo.update``) on its rows of the batch, its random
    draws from its own generator (the global generator holds the agent's state during its update,
    as its single run's holds it after acting), then its networks copied into the stacked rows the
    population acts and values with. The agents' modules hold the networks between updates."""

    def __init__(self, agent: PopulationAgent, algos: Sequence[Any]) -> None:
        self.agent, self.algos = agent, list(algos)

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        n = batch.shape[0] // len(self.algos)
        stats = []
        for i, (algo, g) in enumerate(zip(self.algos, self.agent.generators)):
            device = g.device
            saved = torch.get_rng_state() if device.type == "cpu" else torch.cuda.get_rng_state(device)
            _set_rng(device, g.get_state())
            try:
                stats.append(algo.update(batch[i * n : (i + 1) * n]))
            finally:
                g.set_state(torch.get_rng_state() if device.type == "cpu" else torch.cuda.get_rng_state(device))
                _set_rng(device, saved)
        self.stack_agents()
        return stats

    @torch.no_grad()
    def stack_agents(self) -> None:
        """Every agent's networks (its module's parameters) into the stacked rows."""
        for i, algo in enumerate(self.algos):
            for stacked, module in ((self.agent.actor, algo.agent.actor), (self.agent.critics, algo.agent.critics)):
                row = stacked.row(stacked.flat, i)
                for n, p in module.named_parameters():
                    row[n].copy_(p)

    def unstack_agents(self) -> None:
        """Nothing to move: each agent's algorithm object holds its networks and optimiser."""

    def copy_actors(self, to_modules: bool) -> None:
        if not to_modules:  # the modules hold the networks (a deployed average, too)
            self.stack_agents()


def _set_rng(device: torch.device, state: torch.Tensor) -> None:
    torch.set_rng_state(state) if device.type == "cpu" else torch.cuda.set_rng_state(state, device)


__all__ = ["AgentUpdates", "PopulationPPO"]
