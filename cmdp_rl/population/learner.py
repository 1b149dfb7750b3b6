"""What an update loop asks of P stacked agents (:class:`StackedLearner`; ``algos/ppo.SingleLearner`` answers it
for a run's one agent): the mean per agent, each agent's minibatch order from its own generator, the backward pass
and a StackedAdam step of the agents still stepping; and moving networks and Adam moments between the stacked rows
and each agent's own objects, whose ``state_dict`` is then its single run's."""

from __future__ import annotations

import contextlib
from typing import Any, Iterator, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl.algos.base import TrainingDiverged
from cmdp_rl.algos.minibatch import member_rows
from cmdp_rl.algos.ppo import ppo_update
from cmdp_rl.population.stacked import PopulationAgent, StackedAdam, StackedParams
from cmdp_rl.rollout import keys


class StackedLearner:
    """What an update loop asks of P agents (``algos/ppo.SingleLearner`` answers it for a run). ``whole``
    (``spec.stacked``): every agent's ``ppo.ppo_update`` at once. Else (trust region) each agent's own
    ``policy_update`` on its rows (the global generator holding its stream), then one ``fit_critics``."""

    def __init__(self, agent: PopulationAgent, algos: Sequence[Any], whole: bool) -> None:
        self.agent, self.algos, self.whole = agent, list(algos), whole
        self.rows = torch.arange(agent.num_agents, device=agent.actor.flat.device).unsqueeze(1)
        self.critic_opt = StackedAdam(agent.critics.flat, [a.cfg.critic_lr for a in self.algos])
        self.pairs = [("critics", agent.critics, self.critic_opt, "critic_opt")]  # (module, rows, Adam, optimiser)
        if whole:
            self.actor_opt = StackedAdam(agent.actor.flat, [a.cfg.lr for a in self.algos])
            self.pairs.insert(0, ("actor", agent.actor, self.actor_opt, "actor_opt"))

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        """One iteration for every agent on the ``[P N, T]`` batch; each agent's logged statistics."""
        if self.whole:
            if self.algos[0].cfg.anneal_lr:
                rates = torch.tensor([a.learning_rates() for a in self.algos], dtype=torch.float64)
                self.actor_opt.lr, self.critic_opt.lr = rates[:, 0].clone(), rates[:, 1].clone()
            stats = ppo_update(self.algos, batch, self)
        else:
            stats = self._agent_updates(batch)
        for name, stacked in (("actor", self.agent.actor), ("critics", self.agent.critics)):
            bad = (~torch.isfinite(stacked.flat).all(1)).nonzero().flatten().tolist()
            if bad:
                raise TrainingDiverged(f"agent {bad[0]}: a parameter of the {name} is not finite after the update")
        return stats

    def _agent_updates(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        first = self.algos[0]
        first.gae(batch, self.agent)  # every agent's rows at once
        done = []
        for algo, rows, g in zip(self.algos, member_rows(batch, len(self.algos)), self.agent.generators):
            with _global_generator(g):
                done.append(algo.policy_update(rows))
        self.copy_actors(to_modules=False)
        units, stats = [list(x) for x in zip(*done)]
        stacked = {k: torch.stack([u[k] for u in units]) for k in [*self.agent.in_keys, *first.critics.target_keys()]}
        losses = first.fit_critics(stacked, self, [(self.critic_opt, self.agent.critics)])
        values = {k: v.tolist() for k, v in losses.items()}
        for i, (algo, s) in enumerate(zip(self.algos, stats)):
            s.update({k: v[i] for k, v in values.items()})
            s["lagrange_multiplier"] = algo.lagrange_multiplier
        return stats

    # --- the update loops' calls ---------------------------------------------------------------------
    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """The mean over each agent's rows: ``[P, B, ...]`` -> ``[P]``."""
        return x.reshape(self.agent.num_agents, -1).mean(1)

    def per_member(self, values: Sequence[float]) -> torch.Tensor:
        return torch.tensor(values, dtype=torch.float32, device=self.rows.device)

    def minibatches(self, units: dict, num_minibatches: int, active: Any = True) -> Iterator[dict]:
        """One pass, each agent's units in its own fresh order; one stopped by KL (``active`` false) draws none."""
        total = next(iter(units.values())).shape[1]
        size = total // num_minibatches
        if size < 1:
            raise ValueError(f"{num_minibatches} minibatches of {total} units: at most {total} allowed")
        on = [True] * self.agent.num_agents if active is True else active.tolist()
        ids = torch.arange(total, device=self.rows.device)
        gens = zip(self.agent.generators, on)
        perm = torch.stack([torch.randperm(total, generator=g, device=g.device) if a else ids for g, a in gens])
        shuffled = {k: v[self.rows, perm] for k, v in units.items()}
        for j in range(num_minibatches):
            yield {k: v[:, j * size : (j + 1) * size] for k, v in shuffled.items()}

    def step(
        self, loss: torch.Tensor, optimisers: Sequence[tuple[StackedAdam, StackedParams]], stepping: Any = True
    ) -> None:
        """Backward, clip and step the agents ``stepping`` holds (True: all)."""
        for _, stacked in optimisers:
            stacked.flat.grad = None
        loss.sum().backward()  # agents share no parameter: each one's gradient is its own loss's
        for _, stacked in optimisers:
            stacked.clip_grad_norm_(self.algos[0].cfg.max_grad_norm)  # shared, as every shape and schedule
        for opt, _ in optimisers:
            opt.step(None if stepping is True else stepping)

    def forward(self, mb: dict) -> tuple[Any, dict[str, torch.Tensor]]:
        dist, value, cost_value = self.agent.training_pass(mb[keys.OBS])
        return dist, {"reward": value, "cost": cost_value}

    def dist(self, mb: dict) -> Any:
        return self.agent.head.dist(self.agent.params(mb[keys.OBS]))

    def values(self, mb: dict) -> dict[str, torch.Tensor]:
        return {s: self.agent.value(s, mb[keys.OBS]) for s in self.agent.critic_nets}

    def actor_params(self, units: dict) -> dict[str, torch.Tensor]:
        return self.agent.params(units[keys.OBS])

    def optimisers(self, algos: Sequence[Any]) -> list:
        return [(self.actor_opt, self.agent.actor), (self.critic_opt, self.agent.critics)]

    def fresh_actor_optimiser(self, algos: Sequence[Any]) -> list:
        return [(StackedAdam(self.agent.actor.flat, self.actor_opt.lr.tolist()), self.agent.actor)]

    # --- between the stacked rows and the agents' own objects -------------------------------------------
    @torch.no_grad()
    def copy_actors(self, to_modules: bool) -> None:
        """The stacked actors' rows into each agent's single-run actor (``to_modules``), or back."""
        for i, algo in enumerate(self.algos):
            row = self.agent.actor.row(self.agent.actor.flat, i)
            for n, p in algo.agent.actor.named_parameters():
                p.copy_(row[n]) if to_modules else row[n].copy_(p)

    @torch.no_grad()
    def transfer(self, to_agents: bool) -> None:
        """Each agent's networks and Adam moments into its algorithm object (``to_agents``), whose
        ``state_dict`` is then its single run's; else back, after a resume loaded the objects (no step
        yet: zero moments), the actors too."""
        if not to_agents:
            self.copy_actors(to_modules=False)
        for i, algo in enumerate(self.algos):
            for name, stacked, adam, opt_name in self.pairs:
                opt = getattr(algo, opt_name)
                saved = opt.state_dict()
                rows = [stacked.row(t, i) for t in (stacked.flat, adam.exp_avg, adam.exp_avg_sq)]
                named = getattr(algo.agent, name).named_parameters()
                if to_agents:
                    step = adam.steps[i].to(torch.float32)
                    for k, (n, p) in enumerate(named):
                        p.copy_(rows[0][n])
                        moments = {"exp_avg": rows[1][n].clone(), "exp_avg_sq": rows[2][n].clone()}
                        saved["state"][k] = {"step": step.clone(), **moments}
                    opt.load_state_dict(saved)
                    continue
                adam.steps[i] = 0.0
                for k, (n, p) in enumerate(named):
                    state = saved["state"].get(k, {})
                    for row, value in zip(rows, (p, state.get("exp_avg"), state.get("exp_avg_sq"))):
                        row[n].zero_() if value is None else row[n].copy_(value)
                    adam.steps[i] = float(state.get("step", 0.0))


@contextlib.contextmanager
def _global_generator(g: torch.Generator) -> Iterator[None]:
    """Torch's global generator holding ``g``'s state for the block, ``g`` taking the state it leaves."""
    cpu = g.device.type == "cpu"
    get = torch.get_rng_state if cpu else lambda: torch.cuda.get_rng_state(g.device)
    put = torch.set_rng_state if cpu else lambda s: torch.cuda.set_rng_state(s, g.device)
    saved = get()
    put(g.get_state())
    try:
        yield
    finally:
        g.set_state(get())
        put(saved)
