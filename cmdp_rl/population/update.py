"""The agents' update on the stacked backend: units ``[P, U, ...]``, each agent's permutations from
its generator, per-agent means, per-row clipping, ``StackedAdam``, the KL mask
(:class:`StackedBackend`). :class:`PopulationPPO`, the PPO family's, is every agent's iteration at
once (``algos/update_backend.iterate``, the fused training pass), each agent's own single-run
algorithm object around it. :class:`AgentUpdates`, the trust-region family's, is each agent's own
policy step (``NaturalGradient.policy_update``) on its rows, then every agent's critic regression
at once (``NaturalGradient.fit_critics`` on the stacked backend).
"""

from __future__ import annotations

from typing import Any, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl.algos.base import TrainingDiverged
from cmdp_rl.algos.update_backend import iterate, members
from cmdp_rl.population.agent import PopulationAgent
from cmdp_rl.population.params import StackedAdam, StackedParams
from cmdp_rl.rollout import keys

# A stacked network, its Adam, and the attributes of an agent's algorithm object that hold the
# same network's module (``algo.agent.<name>``) and optimiser.
Pair = tuple[str, StackedParams, StackedAdam, str]


class StackedBackend:
    """The minibatch epochs of P agents side by side (``algos/update_backend.Backend``): a KL limit
    per agent (``kl_limit`` ``[P]``, or None), gradient norms clipped at ``max_grad_norm`` per agent."""

    def __init__(self, agent: PopulationAgent, max_grad_norm: float, kl_limit: torch.Tensor | None) -> None:
        self.agent, self.max_grad_norm, self.kl_limit = agent, max_grad_norm, kl_limit
        self.rows = torch.arange(agent.num_agents, device=agent.actor.flat.device).unsqueeze(1)

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

    def critic_values(self, mb: dict) -> dict[str, torch.Tensor]:
        return {s: self.agent.value(s, mb[keys.OBS]) for s in self.agent.critic_nets}

    def check_finite(self) -> None:
        for name, stacked in (("actor", self.agent.actor), ("critics", self.agent.critics)):
            bad = (~torch.isfinite(stacked.flat).all(1)).nonzero().flatten().tolist()
            if bad:
                raise TrainingDiverged(f"agent {bad[0]}: a parameter of the {name} is not finite after the update")

    def unstack_agents(self) -> None:
        self.transfer(self.algos, self._pairs(), to_agents=True)

    def stack_agents(self) -> None:
        self.transfer(self.algos, self._pairs(), to_agents=False)

    @torch.no_grad()
    def copy_actors(self, to_modules: bool) -> None:
        """The stacked actors' rows into each agent's single-run actor (``to_modules``), or back."""
        for i, algo in enumerate(self.algos):
            row = self.agent.actor.row(self.agent.actor.flat, i)
            for n, p in algo.agent.actor.named_parameters():
                p.copy_(row[n]) if to_modules else row[n].copy_(p)

    def transfer(self, algos: Sequence[Any], pairs: Sequence[Pair], to_agents: bool) -> None:
        """Each agent's networks and Adam moments between the stacked rows and its algorithm object
        (``to_agents``: into its modules and, through ``load_state_dict``, its optimiser, whose
        ``state_dict`` is then its single run's: what a checkpoint holds per agent; else back, after
        the object loaded a resume's state: a parameter without a step yet has zero moments)."""
        with torch.no_grad():
            for i, algo in enumerate(algos):
                for name, stacked, adam, opt_name in pairs:
                    opt, saved = getattr(algo, opt_name), getattr(algo, opt_name).state_dict()
                    rows = [stacked.row(t, i) for t in (stacked.flat, adam.exp_avg, adam.exp_avg_sq)]
                    step = adam.steps[i].to(torch.float32)
                    if not to_agents:
                        adam.steps[i] = 0.0
                    for k, (n, p) in enumerate(getattr(algo.agent, name).named_parameters()):
                        if to_agents:
                            p.copy_(rows[0][n])
                            saved["state"][k] = {
                                "step": step.clone(),
                                "exp_avg": rows[1][n].clone(),
                                "exp_avg_sq": rows[2][n].clone(),
                            }
                            continue
                        state = saved["state"].get(k, {})
                        for row, value in zip(rows, (p, state.get("exp_avg"), state.get("exp_avg_sq"))):
                            row[n].zero_() if value is None else row[n].copy_(value)
                        adam.steps[i] = float(state.get("step", 0.0))
                    if to_agents:
                        opt.load_state_dict(saved)


class PopulationPPO(StackedBackend):
    """P agents' side of the shared update (``algos/update_backend.Backend``). ``algos`` are the
    agents' single-run algorithm objects (PPO or a subclass that keeps ``PPO.update``): each keeps
    its agent's J_c window, multiplier and schedule clock; the networks and optimisers are here."""

    def __init__(self, agent: PopulationAgent, algos: Sequence[Any]) -> None:
        self.algos, device = list(algos), agent.actor.flat.device
        # each algorithm's own coefficient: a regularised multiplier adds its tau to the configured one
        self.entropy_coef = torch.tensor([a.entropy_coef for a in algos], dtype=torch.float32, device=device)
        limits = [a.kl_limit for a in algos]
        kl_limit = None if limits[0] is None else torch.tensor(limits, dtype=torch.float32, device=device)
        super().__init__(agent, self.algos[0].cfg.max_grad_norm, kl_limit)  # shared, as every shape and schedule
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

    def dist(self, mb: dict) -> Any:
        return self.agent.dist(mb[keys.OBS])

    def training_pass(self, mb: dict) -> tuple[Any, dict[str, torch.Tensor]]:
        dist, value, cost_value = self.agent.training_pass(mb[keys.OBS])
        return dist, {"reward": value, "cost": cost_value}

    def _pairs(self) -> list[Pair]:
        return [
            ("actor", self.agent.actor, self.actor_opt, "actor_opt"),
            ("critics", self.agent.critics, self.critic_opt, "critic_opt"),
        ]


class AgentUpdates(StackedBackend):
    """The trust-region family's update of P agents: GAE for all at once (the stacked critics), each
    agent's own policy step on its rows (its single-run ``policy_update``, with the global generator
    holding the agent's stream, as its single run's holds it after acting), its actor then copied
    into the stacked rows the population acts with; then one critic regression for all
    (``fit_critics`` on this backend and a ``StackedAdam`` at each agent's critic rate). The actors
    live in the agents' modules, the critics in the stacked rows (moved at a checkpoint)."""

    def __init__(self, agent: PopulationAgent, algos: Sequence[Any]) -> None:
        self.algos = list(algos)
        super().__init__(agent, self.algos[0].cfg.max_grad_norm, None)
        self.critic_opt = StackedAdam(agent.critics.flat, [a.cfg.critic_lr for a in self.algos])

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        first = self.algos[0]
        first.gae(batch, self.agent)  # every agent's rows at once
        units, stats = [], []
        for algo, rows, g in zip(self.algos, members(batch, len(self.algos)), self.agent.generators):
            with _global_generator(g):
                u, s = algo.policy_update(rows)
            units.append(u)
            stats.append(s)
        self.copy_actors(to_modules=False)
        needed = [*self.agent.in_keys, *first.critics.target_keys()]
        stacked = {k: torch.stack([u[k] for u in units]) for k in needed}
        losses = first.fit_critics(stacked, self, [(self.critic_opt, self.agent.critics)])
        self.check_finite()
        values = {k: v.tolist() for k, v in losses.items()}
        for i, (algo, s) in enumerate(zip(self.algos, stats)):
            s.update({k: v[i] for k, v in values.items()})
            s["lagrange_multiplier"] = algo.lagrange_multiplier
        return stats

    def _pairs(self) -> list[Pair]:
        return [("critics", self.agent.critics, self.critic_opt, "critic_opt")]

    def stack_agents(self) -> None:
        super().stack_agents()
        self.copy_actors(to_modules=False)

    def copy_actors(self, to_modules: bool) -> None:
        """The agents' actors (their modules hold them) into the stacked rows; nothing to bring back."""
        if not to_modules:
            super().copy_actors(False)


class _global_generator:
    """Torch's global generator holding ``g``'s state for the block, ``g`` taking the state it
    leaves; the global state is then what it was."""

    def __init__(self, g: torch.Generator) -> None:
        self.g, self.cpu = g, g.device.type == "cpu"

    def _get(self) -> torch.Tensor:
        return torch.get_rng_state() if self.cpu else torch.cuda.get_rng_state(self.g.device)

    def _set(self, state: torch.Tensor) -> None:
        torch.set_rng_state(state) if self.cpu else torch.cuda.set_rng_state(state, self.g.device)

    def __enter__(self) -> None:
        self.saved = self._get()
        self._set(self.g.get_state())

    def __exit__(self, *exc: Any) -> None:
        self.g.set_state(self._get())
        self._set(self.saved)


__all__ = ["AgentUpdates", "PopulationPPO", "StackedBackend"]
