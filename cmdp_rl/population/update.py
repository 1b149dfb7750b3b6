"""The agents' update, P agents side by side: units ``[P, U, ...]``, each agent's minibatch order
from its own generator, one mean per agent, per-row clipping, ``StackedAdam``, KL early stopping
as a mask over the agents (:class:`StackedBackend`). :class:`PopulationPPO`, the PPO family's, is
every agent's iteration at once (``algos/ppo.ppo_update``, with the fused training pass), each
agent's own single-run algorithm object around it. :class:`AgentUpdates`, the trust-region
family's, is each agent's own policy step (``NaturalGradient.policy_update``) on its rows, then
every agent's critic regression at once (``NaturalGradient.fit_critics`` on this backend).
"""

from __future__ import annotations

from typing import Any, Iterator, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl.algos.base import TrainingDiverged
from cmdp_rl.algos.minibatch import member_rows
from cmdp_rl.algos.ppo import ppo_update
from cmdp_rl.population.agent import PopulationAgent
from cmdp_rl.population.params import StackedAdam, StackedParams
from cmdp_rl.rollout import keys

# A stacked network, its Adam, and the attributes of an agent's algorithm object that hold the
# same network's module (``algo.agent.<name>``) and optimiser.
Pair = tuple[str, StackedParams, StackedAdam, str]
# An optimiser with the stacked parameters it steps (their rows are clipped per agent).
Optimiser = tuple[StackedAdam, StackedParams]


class StackedBackend:
    """What an update loop asks of P agents side by side (``algos/ppo.OneRun`` answers it for a
    run): the reducer is a mean per agent, the optimiser step clips each agent's gradient norm at
    ``max_grad_norm`` and steps the agents still active."""

    def __init__(self, agent: PopulationAgent, max_grad_norm: float) -> None:
        self.agent, self.max_grad_norm = agent, max_grad_norm
        self.rows = torch.arange(agent.num_agents, device=agent.actor.flat.device).unsqueeze(1)

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """The mean over each agent's rows: ``[P, B, ...]`` -> ``[P]``."""
        return x.reshape(self.agent.num_agents, -1).mean(1)

    def per_member(self, values: Sequence[float]) -> torch.Tensor:
        """One number per agent, ``[P]``, as the losses weigh each agent's terms."""
        return torch.tensor(values, dtype=torch.float32, device=self.rows.device)

    def minibatches(self, units: dict, num_minibatches: int, active: Any = True) -> Iterator[dict]:
        """One pass, each agent's units in its own fresh order (from its generator, as its single
        run draws it); an agent that KL early stopping stopped (``active`` false) draws none."""
        total = next(iter(units.values())).shape[1]
        size = total // num_minibatches
        if size < 1:
            raise ValueError(f"{num_minibatches} minibatches of {total} units: at most {total} allowed")
        on = [True] * self.agent.num_agents if active is True else active.tolist()
        perm = torch.stack(
            [
                torch.randperm(total, generator=g, device=g.device) if a else torch.arange(total, device=g.device)
                for g, a in zip(self.agent.generators, on)
            ]
        )
        shuffled = {k: v[self.rows, perm] for k, v in units.items()}
        for j in range(num_minibatches):
            yield {k: v[:, j * size : (j + 1) * size] for k, v in shuffled.items()}

    def step(self, loss: torch.Tensor, optimisers: Sequence[Optimiser], stepping: Any = True) -> None:
        """Backward, clip and step the agents ``stepping`` holds (True: all)."""
        for opt, _ in optimisers:
            opt.zero_grad()
        # The per-agent losses summed: agents share no parameter, so each one's gradient is its own loss's.
        loss.sum().backward()
        for _, stacked in optimisers:
            stacked.clip_grad_norm_(self.max_grad_norm)
        for opt, _ in optimisers:
            opt.step(None if stepping is True else stepping)

    def values(self, mb: dict) -> dict[str, torch.Tensor]:
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
    """P agents' side of the PPO family's update (``algos/ppo.ppo_update``). ``algos`` are the
    agents' single-run algorithm objects (PPO or a subclass that keeps ``PPO.update``): each keeps
    its agent's J_c window, multiplier and schedule clock; the networks and optimisers are here."""

    def __init__(self, agent: PopulationAgent, algos: Sequence[Any]) -> None:
        self.algos = list(algos)
        super().__init__(agent, self.algos[0].cfg.max_grad_norm)  # shared, as every shape and schedule
        rates = [a.learning_rates() for a in self.algos]
        self.actor_opt = StackedAdam(agent.actor.flat, [lr for lr, _ in rates])
        self.critic_opt = StackedAdam(agent.critics.flat, [lr for _, lr in rates])

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        """One iteration for every agent on the ``[P N, T]`` batch; each agent's logged statistics."""
        if self.algos[0].cfg.anneal_lr:
            rates = torch.tensor([a.learning_rates() for a in self.algos], dtype=torch.float64)
            self.actor_opt.lr, self.critic_opt.lr = rates[:, 0].clone(), rates[:, 1].clone()
        stats = ppo_update(self.algos, batch, self)
        self.check_finite()
        return stats

    # --- what the loops ask besides the reducer and the step ---------------------------------------
    def forward(self, mb: dict) -> tuple[Any, dict[str, torch.Tensor]]:
        """The actors' distribution and the critics' values, in one fused pass where it applies."""
        dist, value, cost_value = self.agent.training_pass(mb[keys.OBS])
        return dist, {"reward": value, "cost": cost_value}

    def dist(self, mb: dict) -> Any:
        return self.agent.dist(mb[keys.OBS])

    def actor_params(self, units: dict) -> dict[str, torch.Tensor]:
        return self.agent.params(units[keys.OBS])

    def optimisers(self, algos: Sequence[Any]) -> list[Optimiser]:
        return [(self.actor_opt, self.agent.actor), (self.critic_opt, self.agent.critics)]

    def fresh_actor_optimiser(self, algos: Sequence[Any]) -> list[Optimiser]:
        return [(StackedAdam(self.agent.actor.flat, self.actor_opt.lr.tolist()), self.agent.actor)]

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
        super().__init__(agent, self.algos[0].cfg.max_grad_norm)
        self.critic_opt = StackedAdam(agent.critics.flat, [a.cfg.critic_lr for a in self.algos])

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        first = self.algos[0]
        first.gae(batch, self.agent)  # every agent's rows at once
        units, stats = [], []
        for algo, rows, g in zip(self.algos, member_rows(batch, len(self.algos)), self.agent.generators):
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
