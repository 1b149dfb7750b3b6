"""The PPO-family update of every agent at once, each agent's algorithm arithmetic from its own
single-run algorithm object.

Per iteration, as ``algos/ppo.py``'s ``PPO.update``: torchrl's GAE (``advantages.TwinGAE``) on the
whole ``[P N, T]`` batch (its recursion runs along time, row by row); then each agent's own
algorithm object, on its own rows, estimates J_c and moves its multiplier (``update_multiplier``)
and gives the policy advantage (``policy_advantage``), so whatever an algorithm does there (a
penalty, dual ascent, PID, CRPO's switch, a multiplier of #28's kinds) is its single run's code.
The minibatch step's policy loss is the algorithm's ``surrogate`` with per-agent reductions on
``[P, B, ...]`` (clipped PPO, FOCOPS's projection loss), and the critics' MSE per agent.
Everything that is not elementwise is per agent: advantage normalisation, the minibatch
permutations (each agent's generator, in its single run's order), gradient-norm clipping and Adam
(``params``), KL early stopping (a mask: an agent that stops takes no further step and draws no
further permutation, as its single run breaks out of its loop). The per-agent losses are summed
before one backward pass: agents share no parameter, so each agent's gradient is its own loss's.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl import keys
from cmdp_rl.advantages import TwinGAE
from cmdp_rl.algos.base import TrainingDiverged
from cmdp_rl.algos.cup import HALF
from cmdp_rl.config import RunConfig
from cmdp_rl.population.agent import PopulationAgent
from cmdp_rl.population.params import StackedAdam


class PopulationPPO:
    """``algos`` are the agents' single-run algorithm objects (PPO or a subclass that keeps
    ``PPO.update``): each keeps its agent's J_c window, multiplier and schedule clock; the networks'
    arithmetic and the optimisers are here."""

    def __init__(
        self, cfgs: Sequence[RunConfig], algos: Sequence[Any], agent: PopulationAgent, envs_per_agent: int
    ) -> None:
        first = cfgs[0].algo
        self.cfg = first  # shared options: discounts, epochs, minibatches, clip, max_grad_norm
        self.algos = list(algos)
        self.agent = agent
        self.n = envs_per_agent
        self.gae = TwinGAE(first.gamma, first.cost_gamma, first.gae_lambda)
        device = agent.actor.flat.device
        # each algorithm's own coefficient: a regularised multiplier adds its tau to the configured one
        self.entropy_coef = torch.tensor([a.entropy_coef for a in self.algos], dtype=torch.float32, device=device)
        limits = [a.kl_limit for a in self.algos]
        self.kl_limit = None if limits[0] is None else torch.tensor(limits, dtype=torch.float32, device=device)
        self.lrs = [(c.algo.lr, c.algo.critic_lr) for c in cfgs]
        self.actor_opt = StackedAdam(agent.actor.flat, [lr for lr, _ in self.lrs])
        self.critic_opt = StackedAdam(agent.critics.flat, [lr for _, lr in self.lrs])

    def _mean(self, x: torch.Tensor) -> torch.Tensor:
        """The mean over each agent's rows: ``[P, B, ...]`` -> ``[P]``."""
        return x.reshape(self.agent.num_agents, -1).mean(1)

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        """One iteration for every agent on the ``[P N, T]`` batch; each agent's logged statistics."""
        cfg, P, agent = self.cfg, self.agent.num_agents, self.agent
        if cfg.anneal_lr:  # PPO.update's schedule, per agent
            fracs = [a.anneal_fraction() for a in self.algos]
            self.actor_opt.lr = torch.tensor([f * lr for f, (lr, _) in zip(fracs, self.lrs)], dtype=torch.float64)
            self.critic_opt.lr = torch.tensor([f * lr for f, (_, lr) in zip(fracs, self.lrs)], dtype=torch.float64)
        self.gae(batch, agent)
        advs = []
        for i, algo in enumerate(self.algos):  # J_c, the multiplier and the advantage: the agent's own code
            rows = batch[i * self.n : (i + 1) * self.n]
            algo.update_multiplier(algo.episode_cost.update(rows))
            advs.append(algo.policy_advantage(rows))
        adv = torch.cat(advs)
        if cfg.normalize_advantage:
            a = adv.reshape(P, -1)
            adv = ((a - a.mean(1, keepdim=True)) / (a.std(1, keepdim=True) + 1e-8)).reshape(adv.shape)
        batch.set(keys.POLICY_ADVANTAGE, adv)
        # Training units per agent: [P, N T, ...].
        data = {k: batch.get(k).reshape(P, -1, *batch.get(k).shape[2:]) for k in self.algos[0]._update_keys(batch)}
        sums, counts = self._epochs(data, cfg.update_epochs, self._step)
        means = {k: v / counts for k, v in sums.items()}  # each agent's mean over its minibatches
        if hasattr(self.algos[0], "projection_loss"):  # CUP's second stage (algos/cup.py)
            sums, counts = self._project(batch)
            means.update({k: v / counts for k, v in sums.items()})
        names = [k for k in means if k in self.algos[0].stats]
        values = torch.stack([means[k] for k in names]).tolist()  # [stats, P]: one host sync
        out = []
        for i, algo in enumerate(self.algos):
            stats = {k: values[s][i] for s, k in enumerate(names)}
            for k, v in stats.items():
                if not math.isfinite(v):
                    raise TrainingDiverged(f"agent {i}: {k} is {v}: training diverged")
            stats["lagrange_multiplier"] = algo.lagrange_multiplier
            stats.update(algo.iteration_stats())
            algo.iteration += 1
            out.append(stats)
        for name, stacked in (("actor", agent.actor), ("critics", agent.critics)):
            bad = (~torch.isfinite(stacked.flat).all(1)).nonzero().flatten().tolist()
            if bad:
                raise TrainingDiverged(f"agent {bad[0]}: a parameter of the {name} is not finite after the update")
        return out

    def _epochs(self, data: dict, epochs: int, step: Callable) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """``algos/minibatch.py``'s loop per agent: ``epochs`` passes over ``data`` ``[P, units, ...]``,
        each in a fresh order from every still active agent's generator (an agent stopped early draws
        none, as its single run), ``step(minibatch, active) -> (stats, active)`` on each minibatch.
        Returns the statistics summed over the minibatches each agent evaluated, and their counts."""
        P = self.agent.num_agents
        total = next(iter(data.values())).shape[1]
        size = total // self.cfg.num_minibatches
        device = self.agent.actor.flat.device
        rows = torch.arange(P, device=device).unsqueeze(1)
        active = torch.ones(P, dtype=torch.bool, device=device)
        sums: dict[str, torch.Tensor] = {}
        counts = torch.zeros(P, device=device)
        for _ in range(epochs):
            running = active.tolist()
            if not any(running):
                break
            perm = torch.stack(
                [
                    torch.randperm(total, generator=g, device=g.device) if on else torch.arange(total, device=g.device)
                    for g, on in zip(self.agent.generators, running)
                ]
            )
            shuffled = {k: v[rows, perm] for k, v in data.items()}
            for j in range(self.cfg.num_minibatches):
                evaluated = active.to(counts.dtype)
                stats, active = step({k: v[:, j * size : (j + 1) * size] for k, v in shuffled.items()}, active)
                sums = {k: sums[k] + v if k in sums else v for k, v in stats.items()}
                counts += evaluated
                if self.kl_limit is not None and not active.any().item():
                    break
        return sums, counts

    def _stop(self, kl: torch.Tensor, active: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """KL early stopping per agent: the agents still active after this minibatch's check, and
        those that step on it (``None``: every agent, no limit)."""
        if self.kl_limit is None:
            return active, None
        active = active & ~(kl > self.kl_limit)
        return active, active

    def _kept(self, stats: dict[str, torch.Tensor], evaluated: torch.Tensor) -> dict[str, torch.Tensor]:
        """The statistics detached, zero for the agents that did not evaluate this minibatch."""
        if self.kl_limit is None:  # every agent evaluates every minibatch
            return {k: v.detach() for k, v in stats.items()}
        return {k: torch.where(evaluated, v.detach(), 0.0) for k, v in stats.items()}

    def _step(self, mb: dict[str, torch.Tensor], active: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """One minibatch step of the ``active`` agents: the algorithm's surrogate and the critics'
        regression per agent, one backward, per-agent clipping, Adam. Returns each statistic as
        ``[P]`` (zero where not evaluated) and the agents still active (``PPO.update``: a minibatch
        past the KL limit is evaluated, not stepped)."""
        agent = self.agent
        dist, value, cost_value = agent.training_pass(mb[keys.OBS])
        # The single run's losses (PPO.policy_loss, CriticRegression.losses) with per-agent means.
        loss_pi, stats = self.algos[0].policy_loss(mb, dist, self._mean, self.entropy_coef)
        losses = {
            "loss_pi": loss_pi,
            **self.algos[0].critics.losses(mb, {"reward": value, "cost": cost_value}, self._mean),
        }
        evaluated = active
        active, stepping = self._stop(stats["kl_stop"], active)
        self.actor_opt.zero_grad()
        self.critic_opt.zero_grad()
        sum(loss.sum() for loss in losses.values()).backward()
        agent.actor.clip_grad_norm_(self.cfg.max_grad_norm)
        agent.critics.clip_grad_norm_(self.cfg.max_grad_norm)
        self.actor_opt.step(stepping)
        self.critic_opt.step(stepping)
        return self._kept({**losses, **stats}, evaluated), active

    def _project(self, batch: TensorDictBase) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """CUP's stage 2 (``CUP.project``) per agent: the cost advantage standardised per agent,
        ``pi_{k+1/2}`` as stage 1 left each actor, a fresh Adam at each agent's stage-1 rate,
        ``projection_loss`` with each agent's ``nu`` weight; statistics summed as ``_epochs``."""
        P, agent, algo = self.agent.num_agents, self.agent, self.algos[0]
        units = {
            k: batch.get(k).reshape(P, -1, *batch.get(k).shape[2:]) for k in (keys.ACTION, keys.LOG_PROB, keys.OBS)
        }
        cost_adv = batch.get(keys.COST_ADVANTAGE).reshape(P, -1, 1)
        if self.cfg.normalize_advantage:
            cost_adv = (cost_adv - cost_adv.mean((1, 2), keepdim=True)) / (cost_adv.std((1, 2), keepdim=True) + 1e-8)
        units[keys.COST_ADVANTAGE] = cost_adv
        with torch.no_grad():  # pi_{k+1/2}: each actor as stage 1 left it
            units.update({(HALF, k): v for k, v in agent.params(units[keys.OBS]).items()})
        coef = [a.projection_coef() for a in self.algos]
        nu_coef = torch.tensor(coef, dtype=torch.float32, device=cost_adv.device).view(-1, 1, 1)
        opt = StackedAdam(agent.actor.flat, self.actor_opt.lr.tolist())

        def step(mb: dict, active: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
            loss, kl = algo.projection_loss(agent.dist(mb[keys.OBS]), mb, nu_coef, self._mean)
            evaluated = active
            active, stepping = self._stop(kl.detach(), active)
            opt.zero_grad()
            loss.sum().backward()
            agent.actor.clip_grad_norm_(self.cfg.max_grad_norm)
            opt.step(stepping)
            stats = {"loss_projection": loss, "kl_projection": kl}
            return self._kept(stats, evaluated), active

        return self._epochs(units, self.cfg.projection_epochs, step)

    def _pairs(self) -> list[tuple[str, Any, StackedAdam, str]]:
        return [
            ("actor", self.agent.actor, self.actor_opt, "actor_opt"),
            ("critics", self.agent.critics, self.critic_opt, "critic_opt"),
        ]

    def unstack_agents(self) -> None:
        """Each agent's networks and Adam moments into its single-run algorithm object, whose
        ``state_dict`` is then its single run's (what a checkpoint holds per agent)."""
        for i, algo in enumerate(self.algos):
            self.agent.load_into(i, algo.agent)
            for name, stacked, stacked_opt, opt_name in self._pairs():
                opt, moments = getattr(algo, opt_name), stacked_opt.agent_state(i, stacked)
                step = stacked_opt.steps[i].to(torch.float32)
                for n, p in getattr(algo.agent, name).named_parameters():
                    opt.state[p] = {"step": step.clone(), **moments[n]}

    def stack_agents(self) -> None:
        """The inverse of :meth:`unstack_agents`: after each agent's algorithm object loaded its
        state (a resume), its networks and Adam moments into the stacked ones."""
        for i, algo in enumerate(self.algos):
            for name, stacked, stacked_opt, opt_name in self._pairs():
                module, opt = getattr(algo.agent, name), getattr(algo, opt_name)
                stacked.load_agent(i, module)
                stacked_opt.load_agent(i, stacked, {n: opt.state.get(p, {}) for n, p in module.named_parameters()})


__all__ = ["PopulationPPO"]
