"""P agents' networks as one tensor program, each agent's numbers its single run's. Each agent's networks, built
by the single-run code under its seed, are rows of two leaves ``[P, n]`` (:class:`StackedParams`): one Adam over
them is P Adams (:class:`StackedAdam`), clipping reduces over dim 1, a layer is one ``baddbmm`` (no slower than
``vmap``, docs/population.md). :class:`PopulationAgent` acts and values for the collector and GAE as an ``Agent``
does, each agent drawing its actions from its own generator."""

from __future__ import annotations

import itertools
from typing import Sequence

import torch
from tensordict import TensorDictBase
from torch import distributions as D
from torch import nn

from cmdp_rl.policies.agent import Agent
from cmdp_rl.policies.distributions import GaussianHead
from cmdp_rl.policies.mlp import Tanh
from cmdp_rl.rollout import keys


class StackedParams:
    """The parameters of ``modules`` of P agents (one architecture) as one leaf ``[P, n]``."""

    def __init__(self, per_agent: Sequence[nn.Module], device: torch.device) -> None:
        self.shapes = {n: p.shape for n, p in per_agent[0].named_parameters()}
        sizes = [s.numel() for s in self.shapes.values()]
        self.offsets = {n: (end - k, end) for n, k, end in zip(self.shapes, sizes, itertools.accumulate(sizes))}
        rows = [torch.cat([p.detach().reshape(-1) for p in m.parameters()]) for m in per_agent]
        self.flat = torch.stack(rows).to(device).requires_grad_(True)

    def view(self, name: str) -> torch.Tensor:
        """Parameter ``name`` of every agent, ``[P, *shape]``."""
        return self.flat[:, slice(*self.offsets[name])].view(self.flat.shape[0], *self.shapes[name])

    def row(self, t: torch.Tensor, i: int) -> dict[str, torch.Tensor]:
        """Agent ``i``'s row of ``t`` (``[P, n]``: these parameters or their Adam moments) by name."""
        return {n: t[i, a:b].view(self.shapes[n]) for n, (a, b) in self.offsets.items()}

    def clip_grad_norm_(self, max_norm: float) -> None:
        """``nn.utils.clip_grad_norm_`` per agent (torch's coefficient ``min(1, max_norm / (norm + 1e-6))``)."""
        coef = (max_norm / (torch.linalg.vector_norm(self.flat.grad, dim=1) + 1e-6)).clamp_(max=1.0)
        self.flat.grad.mul_(coef.unsqueeze(1))

    def sequential(self, net: nn.Sequential, prefix: str, x: torch.Tensor) -> torch.Tensor:
        """The single-run MLP ``net`` on ``x [P, B, in]``, per agent, with the parameters ``prefix.<i>.*``."""
        for i, module in enumerate(net):
            if isinstance(module, nn.Linear):
                w, b = self.view(f"{prefix}.{i}.weight"), self.view(f"{prefix}.{i}.bias")
                x = torch.baddbmm(b.unsqueeze(1), x, w.transpose(1, 2))
            else:  # elementwise activation
                x = module(x)
        return x


class StackedAdam:
    """Adam (Kingma & Ba, 2015) on a ``[P, n]`` leaf with one learning rate per agent: torch's Adam
    takes one per parameter group, and a row cannot be a group. Torch's formulas (bias corrections in
    float64 on the host, as its fused CPU kernel); equal to the single run's to float rounding."""

    def __init__(self, params: torch.Tensor, lr: Sequence[float], betas=(0.9, 0.999), eps: float = 1e-8) -> None:
        self.params, self.lr, self.eps = params, torch.tensor(list(lr), dtype=torch.float64), eps
        self.beta1, self.beta2 = betas
        self.steps = torch.zeros(params.shape[0], dtype=torch.float64)  # per agent: KL early stopping skips some
        self.exp_avg, self.exp_avg_sq = torch.zeros_like(params), torch.zeros_like(params)

    @torch.no_grad()
    def step(self, active: torch.Tensor | None = None) -> None:
        """One step of every agent, or of those where ``active`` (``[P]`` bool) holds."""
        g = self.params.grad
        if active is not None:
            keep = ~active.unsqueeze(1).to(g.device)
            old = (self.params.clone(), self.exp_avg.clone(), self.exp_avg_sq.clone())
        self.steps += 1 if active is None else active.to(torch.float64).cpu()
        self.exp_avg.lerp_(g, 1 - self.beta1)
        self.exp_avg_sq.mul_(self.beta2).addcmul_(g, g, value=1 - self.beta2)
        bias1 = 1 - self.beta1**self.steps
        bias2_sqrt = (1 - self.beta2**self.steps).sqrt()
        step_size = (self.lr / bias1).to(self.params.dtype).to(self.params.device).unsqueeze(1)
        denom = (self.exp_avg_sq.sqrt() / bias2_sqrt.to(self.params.dtype).to(g.device).unsqueeze(1)).add_(self.eps)
        self.params.sub_(step_size * self.exp_avg / denom)
        if active is not None:
            for now, before in zip((self.params, self.exp_avg, self.exp_avg_sq), old):
                now.copy_(torch.where(keep, before, now))


class FusedTanhMLP(torch.autograd.Function):
    """The actor's output network and both critics (tanh MLPs of one shape) as 3P networks, ``x [3P, B,
    in] -> [3P, B, out]``; the backward writes each gradient straight into the flat ones (through
    autograd: a dozen nodes per layer, a slow weight-gradient layout; docs/population.md). ``layout``:
    per layer, per group (actor, reward, cost) ``(flat, w_from, w_to, b_from, b_to)``, and ``(out, in)``."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, actor: torch.Tensor, critics: torch.Tensor, layout: tuple) -> torch.Tensor:
        flats, p = (actor, critics), actor.shape[0]
        weights, hs, h = [], [x], x
        for layer, (groups, (out, inp)) in enumerate(layout):
            w = torch.cat([flats[f][:, wa:wb].view(p, out, inp) for f, wa, wb, _, _ in groups])
            b = torch.cat([flats[f][:, ba:bb] for f, _, _, ba, bb in groups])
            h = torch.baddbmm(b.unsqueeze(1), h, w.transpose(1, 2))
            weights.append(w)
            if layer < len(layout) - 1:  # policies.mlp.Tanh, in place on a fresh tensor
                cpu = h.device.type == "cpu" and h.numel() >= Tanh.MIN_NUMEL
                h = h.mul_(2).sigmoid_().mul_(2).sub_(1) if cpu else h.tanh_()
                hs.append(h)
        ctx.layout, ctx.shapes = layout, (actor.shape, critics.shape)
        ctx.save_for_backward(*weights, *hs)
        return h

    @staticmethod
    def backward(ctx, g: torch.Tensor):
        n = len(ctx.layout)
        weights, hs = ctx.saved_tensors[:n], ctx.saved_tensors[n:]
        grads = (g.new_zeros(ctx.shapes[0]), g.new_zeros(ctx.shapes[1]))
        p, g = ctx.shapes[0][0], g.contiguous()
        for layer in range(n - 1, -1, -1):
            groups, (out, inp) = ctx.layout[layer]
            gw = torch.bmm(hs[layer].transpose(1, 2), g).transpose(1, 2)  # (h^T g)^T: faster when ``in`` is small
            gb = g.sum(1)
            for s, (f, wa, wb, ba, bb) in enumerate(groups):
                grads[f][:, wa:wb].view(p, out, inp).copy_(gw[s * p : (s + 1) * p])
                grads[f][:, ba:bb].copy_(gb[s * p : (s + 1) * p])
            if layer > 0:  # one output: an outer product, the same products as bmm's at a quarter of its time
                g = g * weights[layer] if out == 1 else torch.bmm(g, weights[layer])
                g = torch.ops.aten.tanh_backward.grad_input(g, hs[layer], grad_input=g)
        return None, grads[0], grads[1], None


class PopulationAgent:
    """What the collector and GAE ask of an :class:`~cmdp_rl.policies.agent.Agent`, for P MLP agents
    on the flat env batch ``[P N, ...]``; ``agents[0]`` gives the architecture and the head."""

    in_keys = [keys.OBS]
    recurrent = False

    def __init__(self, agents: Sequence[Agent], generators: Sequence[torch.Generator], device: torch.device) -> None:
        self.head = agents[0].actor.head  # a Box's Gaussian or a Discrete's categorical (spec.unbatched_head)
        self.actor_net = self.head.net
        self.critic_nets = {s: c.net for s, c in agents[0].critics.items()}
        self.actor = StackedParams([a.actor for a in agents], device)
        self.critics = StackedParams([a.critics for a in agents], device)
        self.generators = list(generators)
        self.num_agents = len(agents)
        nets = [self.actor_net, *self.critic_nets.values()]
        nets = [[(type(m), [p.shape for p in m.parameters()]) for m in n] for n in nets]
        types, linears = [t for t, _ in nets[0]], range(0, len(nets[0]), 2)
        self.layout = None  # the fused pass: Gaussian tanh MLPs of one shape, one cost (Reach1D)
        if isinstance(self.head, GaussianHead) and len(nets) == 3 and nets[0] == nets[1] == nets[2]:
            if types == [nn.Linear, Tanh] * (len(types) // 2) + [nn.Linear]:
                o, groups = (self.actor.offsets, self.critics.offsets), [(0, "head"), (1, "reward"), (1, "cost")]
                at = [
                    [(f, *o[f][f"{g}.net.{i}.weight"], *o[f][f"{g}.net.{i}.bias"]) for f, g in groups] for i in linears
                ]
                self.layout = tuple((tuple(a), tuple(self.actor_net[i].weight.shape)) for a, i in zip(at, linears))

    def params(self, obs: torch.Tensor | None, out: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The head's distribution parameters per agent on ``obs [P, rows, obs]`` (or its network's ``out``)."""
        out = self.actor.sequential(self.actor_net, "head.net", obs) if out is None else out
        log_std = self.actor.view("head.log_std").unsqueeze(1) if isinstance(self.head, GaussianHead) else None
        return self.head.params(out, log_std)

    def training_pass(self, obs: torch.Tensor) -> tuple[D.Distribution, torch.Tensor, torch.Tensor]:
        """The action distribution and both critics' values on a minibatch ``[P, B, obs]``."""
        if self.layout is None:
            return self.head.dist(self.params(obs)), self.value("reward", obs), self.value("cost", obs)
        x = FusedTanhMLP.apply(obs.repeat(3, 1, 1), self.actor.flat, self.critics.flat, self.layout)
        net, reward, cost = x.split(self.num_agents)
        return self.head.dist(self.params(None, net)), reward, cost

    def value(self, signal: str, obs: torch.Tensor) -> torch.Tensor:
        return self.critics.sequential(self.critic_nets[signal], f"{signal}.net", obs)

    def training_units(self, data: dict) -> dict:
        """Entries of the ``[P N, T, ...]`` batch as each agent's training units, ``[P, N T, ...]``."""
        return {k: v.reshape(self.num_agents, -1, *v.shape[2:]) for k, v in data.items()}

    def _agents(self, x: torch.Tensor) -> torch.Tensor:  # [P N, (T,) features] -> [P, rows, features]
        return x.reshape(self.num_agents, -1, x.shape[-1])

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
            eps = [torch.empty(loc.shape[1:], device=loc.device).normal_(generator=g) for g in self.generators]
            action = loc + torch.stack(eps) * scale
        out = {k: v.reshape(-1, v.shape[-1]) for k, v in {**params, keys.ACTION: action}.items()}
        return {**out, keys.LOG_PROB: dist.log_prob(action).reshape(-1)}

    @torch.no_grad()
    def rollout_values(self, batch: TensorDictBase, signal: str) -> tuple[torch.Tensor, torch.Tensor]:
        """``(V(obs), V(next obs))`` of ``[P N, T]`` as ``Agent.rollout_values``; every next obs valued (one call, not P)."""
        rows, T = batch.shape
        values = self.value(signal, self._agents(batch.get(keys.OBS))).reshape(rows, T, -1)
        next_all = self.value(signal, self._agents(batch.get((keys.NEXT, keys.OBS)))).reshape(rows, T, -1)
        fresh = batch.get((keys.NEXT, keys.DONE)).clone()
        fresh[:, -1] = True
        return values, torch.where(fresh, next_all, torch.cat([values[:, 1:], next_all[:, -1:]], 1))
