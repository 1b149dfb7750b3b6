"""Acting and valuing for all agents at once: the collector's and GAE's side of a population.

:class:`PopulationAgent` offers what :class:`~cmdp_rl.rollout.collector.Collector` and
:class:`~cmdp_rl.rollout.advantages.TwinGAE` ask of an :class:`~cmdp_rl.policies.agent.Agent` (``in_keys``,
``initial_state``, ``act``, ``rollout_values``) on the population's flat env batch ``[P N, ...]``,
so the single-run collector and torchrl's GAE run unchanged. Inside, entries are viewed as
``[P, rows, ...]`` and every network is the single-run MLP applied per agent with stacked
parameters (``params.sequential``). Each agent samples its actions from its own generator, in the
single run's order (``Normal.rsample``: ``loc + eps * scale``, ``eps`` drawn by ``normal_`` on the
action's shape), so agent i's actions are those of its single run.
"""

from __future__ import annotations

from typing import Sequence

import torch
from tensordict import TensorDictBase
from torch import distributions as D
from torch import nn

from cmdp_rl.config.validation import ConfigError
from cmdp_rl.policies.agent import Agent
from cmdp_rl.policies.distributions import GaussianHead
from cmdp_rl.policies.mlp import Tanh
from cmdp_rl.population.fused import FusedTanhMLP, layout
from cmdp_rl.population.params import StackedParams, sequential, template
from cmdp_rl.population.spec import unbatched_head
from cmdp_rl.rollout import keys


class PopulationAgent:
    """P MLP agents: ``template`` (agent 0's single-run module) gives the architecture and the
    distribution head, ``actor`` and ``critics`` the stacked parameters, ``generators`` each
    agent's random stream."""

    in_keys = [keys.OBS]
    recurrent = False

    def __init__(self, agents: Sequence[Agent], generators: Sequence[torch.Generator], device: torch.device) -> None:
        self.head = agents[0].actor.head
        why = unbatched_head(self.head)
        if why is not None:  # trainer.train routes such agents to the single-run path first
            raise ConfigError(f"population: {why}")
        self.actor_net, self.critic_nets = template(agents[0])
        self.actor = StackedParams([a.actor for a in agents], device)
        self.critics = StackedParams([a.critics for a in agents], device)
        self.generators = list(generators)
        self.num_agents = len(agents)
        # Tanh MLPs of one shape (one action dimension, one cost: Reach1D): the actor and both
        # critics as one autograd node with a hand-written backward (population/fused.py).
        nets = (self.actor_net, *self.critic_nets.values())
        shapes = [[tuple(p.shape) for p in net.parameters()] for net in nets]
        linears = [i for i, m in enumerate(self.actor_net) if isinstance(m, nn.Linear)]
        self.layout = None
        if (
            isinstance(self.head, GaussianHead)
            and len(nets) == 3
            and all(s == shapes[0] for s in shapes)
            and all(isinstance(m, (nn.Linear, Tanh)) for m in self.actor_net)
            and all(isinstance(self.actor_net[i + 1], Tanh) for i in linears[:-1])
        ):
            self.layout = layout(
                self.actor,
                self.critics,
                [(0, "head.net"), (1, "reward.net"), (1, "cost.net")],
                linears,
                [tuple(self.actor_net[i].weight.shape) for i in linears],
            )

    # --- the networks on [P, rows, ...] ------------------------------------------------------------
    def params(self, obs: torch.Tensor) -> dict[str, torch.Tensor]:
        """The head's distribution parameters per agent, as its ``forward`` computes them."""
        return self._head(sequential(self.actor_net, "head.net", self.actor, obs))

    def _head(self, out: torch.Tensor) -> dict[str, torch.Tensor]:
        gaussian = isinstance(self.head, GaussianHead)
        return self.head.params(out, self.actor.view("head.log_std").unsqueeze(1) if gaussian else None)

    def training_pass(self, obs: torch.Tensor) -> tuple[D.Distribution, torch.Tensor, torch.Tensor]:
        """The action distribution and both critics' values on a minibatch ``[P, B, obs]``: one
        batched program over 3P networks where they are fused (the measured effect is in
        docs/population.md), else each network over the P agents."""
        if self.layout is None:
            return self.dist(obs), self.value("reward", obs), self.value("cost", obs)
        x = FusedTanhMLP.apply(obs.repeat(3, 1, 1), self.actor.flat, self.critics.flat, self.layout)
        net, reward, cost = x.split(self.num_agents)
        return self.head.dist(self._head(net)), reward, cost

    def dist(self, obs: torch.Tensor) -> D.Distribution:
        return self.head.dist(self.params(obs))

    def value(self, signal: str, obs: torch.Tensor) -> torch.Tensor:
        return sequential(self.critic_nets[signal], f"{signal}.net", self.critics, obs)

    def training_units(self, data: dict) -> dict:
        """Entries of the ``[P N, T, ...]`` batch as each agent's training units, ``[P, N T, ...]``."""
        return {k: v.reshape(self.num_agents, -1, *v.shape[2:]) for k, v in data.items()}

    def _agents(self, x: torch.Tensor) -> torch.Tensor:
        """A flat ``[P N, ...]`` (or ``[P N, T, ...]``) entry as ``[P, rows, features]``."""
        return x.reshape(self.num_agents, -1, x.shape[-1])

    # --- what the collector asks ----------------------------------------------------------------
    def initial_state(self, num_envs: int, device: torch.device | str = "cpu") -> dict:
        return {}

    @torch.no_grad()
    def act(self, d: dict, deterministic: bool = False) -> dict:
        params = self.params(self._agents(d[keys.OBS]))
        dist = self.head.dist(params)
        if deterministic:
            action = dist.deterministic_sample
        elif keys.LOGITS in params:  # Categorical.sample's multinomial, from each agent's generator
            probs = dist.probs
            draws = [torch.multinomial(p, 1, True, generator=g).T for p, g in zip(probs, self.generators)]
            action = torch.stack(draws).reshape(*probs.shape[:-1], 1)
        else:  # Normal.rsample: loc + eps * scale, eps by normal_ on the action's shape
            loc, scale = params[keys.LOC], params[keys.SCALE]
            eps = torch.stack(
                [torch.empty(loc.shape[1:], device=loc.device).normal_(generator=g) for g in self.generators]
            )
            action = loc + eps * scale
        log_prob = dist.log_prob(action)
        flat = self.num_agents * action.shape[1]
        out = {k: v.reshape(flat, -1) for k, v in params.items()}
        return {**out, keys.ACTION: action.reshape(flat, -1), keys.LOG_PROB: log_prob.reshape(flat)}

    # --- what GAE asks ---------------------------------------------------------------------------
    @torch.no_grad()
    def rollout_values(self, batch: TensorDictBase, signal: str) -> tuple[torch.Tensor, torch.Tensor]:
        """``(V(obs), V(next obs))`` of a ``[P N, T]`` batch, as ``Agent.rollout_values`` gives
        them for each agent's rows: a step's next value is the following step's value unless its
        episode ended there or it is the last step. Here the critic values every next observation
        (the fresh steps' count differs per agent, and one batched call is cheaper than P)."""
        rows, T = batch.shape
        values = self.value(signal, self._agents(batch.get(keys.OBS))).reshape(rows, T, -1)
        next_all = self.value(signal, self._agents(batch.get((keys.NEXT, keys.OBS)))).reshape(rows, T, -1)
        fresh = batch.get((keys.NEXT, keys.DONE)).clone()
        fresh[:, -1] = True
        next_values = torch.empty_like(values)
        next_values[:, :-1] = values[:, 1:]
        next_values[:, -1] = next_all[:, -1]
        next_values = torch.where(fresh, next_all, next_values)
        return values, next_values


__all__ = ["PopulationAgent"]
