"""What one PPO-Lagrangian minibatch step costs at ``env=safe_nav``'s default shape, and what public
means would cut it: the measurement behind docs/throughput.md's "the update" paragraph.

    python experiments/speed/update_minibatch_cost.py [--obs-dim 60] [--batch 256] [--steps 400]

A stand-alone replica of the step (not the package's update, which another change rewrites): an
actor MLP (obs -> 64 -> 64 -> 2, tanh) with a state-independent log-std, the clipped surrogate on
a Gaussian's log-probability, two critic MLPs (obs -> 64 -> 64 -> 1) regressed by MSE, one backward
pass, gradient-norm clipping per optimiser, and two fused Adams (``torch.optim.Adam(fused=True)``).
Rows, each in microseconds per minibatch step and process CPU time (torch at one thread):

- ``eager``: the step as written above;
- ``eager, actor only`` and ``eager, critics only``: the two halves apart (what overlapping the
  critics' half with the next rollout could hide);
- ``torch.func critics``: both critics as one batched network (``torch.func.stack_module_state`` +
  ``vmap``): fewer, larger kernels;
- ``torch.compile loss``: the forward and backward compiled by inductor (the optimiser eager);
- ``kernels floor``: the same step at a batch of 8 rows, i.e. what the step costs besides arithmetic.

None of the faster variants is bit-identical to the eager step in general (batched or fused kernels
sum in another order); each would need its own tolerance.
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import time
from typing import Callable

import torch
from torch import nn


def mlp(i: int, o: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(i, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, o))


class Replica:
    """The networks, optimisers and one minibatch of data."""

    def __init__(self, obs_dim: int, batch: int) -> None:
        torch.manual_seed(0)
        self.actor, self.log_std = mlp(obs_dim, 2), nn.Parameter(torch.full((2,), -0.5))
        self.critics = nn.ModuleList([mlp(obs_dim, 1), mlp(obs_dim, 1)])
        self.actor_params = [*self.actor.parameters(), self.log_std]
        self.critic_params = list(self.critics.parameters())
        self.actor_opt = torch.optim.Adam(self.actor_params, lr=3e-4, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=1e-3, fused=True)
        self.obs, self.act = torch.randn(batch, obs_dim), torch.randn(batch, 2)
        self.old_logp, self.adv = torch.randn(batch), torch.randn(batch)
        self.targets = torch.randn(2, batch, 1)

    def actor_loss(self, obs: torch.Tensor) -> torch.Tensor:
        loc, std = self.actor(obs), self.log_std.exp()
        logp = (-((self.act - loc) ** 2) / (2 * std**2) - self.log_std - math.log(math.sqrt(2 * math.pi))).sum(-1)
        ratio = (logp - self.old_logp).exp()
        return -torch.minimum(ratio * self.adv, ratio.clamp(0.8, 1.2) * self.adv).mean()

    def critic_loss(self, obs: torch.Tensor) -> torch.Tensor:
        return sum(((c(obs) - t) ** 2).mean() for c, t in zip(self.critics, self.targets))

    def step(self, loss: torch.Tensor, groups: list) -> None:
        loss.backward()
        for opt, params in groups:
            torch.nn.utils.clip_grad_norm_(params, 0.5, foreach=True)
            opt.step()
            opt.zero_grad(set_to_none=True)


def eager(r: Replica, parts: str = "both") -> Callable[[], None]:
    groups = {"actor": [(r.actor_opt, r.actor_params)], "critics": [(r.critic_opt, r.critic_params)]}
    groups["both"] = groups["actor"] + groups["critics"]

    def run() -> None:
        loss = 0.0
        if parts in ("both", "actor"):
            loss = loss + r.actor_loss(r.obs)
        if parts in ("both", "critics"):
            loss = loss + r.critic_loss(r.obs)
        r.step(loss, groups[parts])

    return run


def func_critics(r: Replica) -> Callable[[], None]:
    """The two critics as one network of stacked parameters, evaluated by ``vmap``."""
    from torch.func import functional_call, stack_module_state, vmap

    params, buffers = stack_module_state(list(r.critics))
    params = {k: nn.Parameter(v) for k, v in params.items()}
    opt = torch.optim.Adam(params.values(), lr=1e-3, fused=True)
    base = copy.deepcopy(r.critics[0]).to("meta")

    def one(p, b, obs):
        return functional_call(base, (p, b), (obs,))

    batched = vmap(one, in_dims=(0, 0, None))

    def run() -> None:
        values = batched(params, buffers, r.obs)  # [2, B, 1]
        loss = r.actor_loss(r.obs) + ((values - r.targets) ** 2).mean(dim=(1, 2)).sum()
        r.step(loss, [(r.actor_opt, r.actor_params), (opt, list(params.values()))])

    return run


def compiled(r: Replica) -> Callable[[], None]:
    loss_fn = torch.compile(lambda obs: r.actor_loss(obs) + r.critic_loss(obs))
    groups = [(r.actor_opt, r.actor_params), (r.critic_opt, r.critic_params)]

    def run() -> None:
        r.step(loss_fn(r.obs), groups)

    return run


def per_step_us(run: Callable[[], None], steps: int) -> float:
    for _ in range(20):  # warm-up (and compilation)
        run()
    c0 = time.process_time()
    for _ in range(steps):
        run()
    return (time.process_time() - c0) / steps * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--obs-dim", type=int, default=60, help="PointGoal1's observation")
    parser.add_argument("--batch", type=int, default=256, help="rows per minibatch (2048 / 8 at the defaults)")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--rounds", type=int, default=2, help="rows measured this many times, alternated")
    parser.add_argument("--no-compile", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows: dict[str, Callable[[], None]] = {
        "eager": eager(Replica(args.obs_dim, args.batch)),
        "eager, actor only": eager(Replica(args.obs_dim, args.batch), "actor"),
        "eager, critics only": eager(Replica(args.obs_dim, args.batch), "critics"),
        "torch.func critics": func_critics(Replica(args.obs_dim, args.batch)),
        "kernels floor (batch 8)": eager(Replica(args.obs_dim, 8)),
    }
    if not args.no_compile:
        rows["torch.compile loss"] = compiled(Replica(args.obs_dim, args.batch))
    print(f"{os.cpu_count()} cores; load average {os.getloadavg()}")
    for k in range(args.rounds):
        for name, run in rows.items():
            us = per_step_us(run, args.steps)
            print(f"round {k + 1}  {name:<26} {us:7.0f} us CPU per minibatch step   load {os.getloadavg()[0]:.2f}")


__all__ = ["Replica", "main"]
