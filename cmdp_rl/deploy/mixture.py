"""The deployed policy of ``deploy.policy: mixture``: at most ``deploy.snapshots`` snapshots of the actor over
the last ``deploy.window`` of the iterations, one drawn per EPISODE and followed until it ends, whose occupancy
is the iterates' average, what a primal-dual method's guarantees are about (docs/constraint_satisfaction.md).
The draw is a carried state of the actor's body (``keys.MIXTURE_MEMBER``), drawn where ``is_init``, so
everything that runs an agent runs a mixture unchanged; its members are memoryless (``policy=mlp``)."""

from __future__ import annotations

import copy
import math

import torch
from torch import nn

from cmdp_rl.policies.agent import Actor, Agent, Body, Entries
from cmdp_rl.rollout import keys


class IterateSnapshots:
    """The actor's state every ``stride = ceil(W / size)`` iterations of a window of W, ending with the last."""

    def __init__(self, first_iteration: int, iterations: int, size: int) -> None:
        self.first_iteration, self.iterations = first_iteration, iterations
        self.stride = math.ceil((iterations - first_iteration + 1) / size)
        self.taken: list[int] = []
        self.members: list[dict[str, torch.Tensor]] = []
        # deploy.weights=feasible: each member's weight and measured value (selection.py); None: uniform.
        self.weights: list[float] | None = None
        self.values: list[dict] | None = None
        self.feasible: bool | None = None
        self.margin: float | None = None  # the standard errors its members' costs were taken high
        self.valuation_steps: int | None = None  # the env steps valuing the members took

    @property
    def count(self) -> int:
        return len(self.members)

    def wants(self, iteration: int) -> bool:
        return iteration >= self.first_iteration and (self.iterations - iteration) % self.stride == 0

    @torch.no_grad()
    def update(self, module: nn.Module, iteration: int) -> None:
        self.taken.append(iteration)
        self.members.append({k: v.detach().clone() for k, v in module.state_dict().items()})

    def adopt(self, state: dict) -> None:
        """Resume from a saved state; on a moved window, only the snapshots this window also takes, unweighted."""
        if (state["first_iteration"], state["stride"]) == (self.first_iteration, self.stride):
            self.load_state_dict(state)
            return
        kept = [(it, m) for it, m in zip(state["taken"], state["members"]) if self.wants(int(it))]
        self.taken = [int(it) for it, _ in kept]
        self.members = [{k: v.clone() for k, v in m.items()} for _, m in kept]

    def state_dict(self) -> dict:
        members = [{k: v.clone() for k, v in m.items()} for m in self.members]
        out = dict(first_iteration=self.first_iteration, stride=self.stride, taken=list(self.taken), members=members)
        return out | dict(weights=self.weights, values=self.values, feasible=self.feasible)

    def load_state_dict(self, state: dict) -> None:
        self.taken = [int(i) for i in state["taken"]]
        self.members = [{k: v.clone() for k, v in m.items()} for m in state["members"]]
        self.weights = None if state.get("weights") is None else [float(w) for w in state["weights"]]
        self.values, self.feasible = state.get("values"), state.get("feasible")

    def result_keys(self, weighting: str) -> dict:
        """What ``eval.json`` records of the deployed mixture (its iterations; weights, feasibility, values)."""
        out = {"mixture_iterations": list(self.taken), "mixture_weights": weighting}
        if self.weights is not None:
            out.update(
                mixture_deployed=[list(m) for m in self.deployed_members()],
                mixture_feasible=self.feasible,
                mixture_member_values=self.values,
            )
        if self.margin is not None:  # chosen in this process (a checkpoint keeps weights and values only)
            out.update(mixture_margin=self.margin, mixture_valuation_steps=self.valuation_steps)
        return out

    def deployed_members(self) -> list[tuple[int, float]]:
        """(iteration, weight) of each member the deployed mixture draws from."""
        weights = self.weights or [1.0 / len(self.members)] * len(self.members)
        return [(it, w) for it, w in zip(self.taken, weights) if w > 0]

    def actors(self, template: Actor) -> list[Actor]:
        """One copy of ``template`` per member, holding that member's state."""
        out = []
        for state in self.members:
            actor = copy.deepcopy(template)
            actor.load_state_dict(state)
            out.append(actor)
        return out

    def deploy(self, agent: Agent) -> None:
        """Make ``agent`` act with the mixture (nothing when no snapshot was taken)."""
        if not self.members:
            return
        actors = self.actors(agent.actor)
        if self.weights is None:
            agent.actor = mixture_actor(actors)
        else:  # only the members with weight: at most K + 1 of them (selection.py)
            chosen = [(a, w) for a, w in zip(actors, self.weights) if w > 0]
            agent.actor = mixture_actor([a for a, _ in chosen], [w for _, w in chosen])


class MixtureBody(Body):
    """Runs the member actors and keeps each row's member's parameters (``keys.MIXTURE_MEMBER``)."""

    state_keys = (keys.MIXTURE_MEMBER,)

    def __init__(
        self, members: list[Actor], weights: list[float] | None = None, assigned: torch.Tensor | None = None
    ) -> None:
        super().__init__()
        if any(m.body.recurrent or m.body.state_keys for m in members):
            raise ValueError("a mixture's members must be memoryless actors (policy=mlp)")
        self.members = nn.ModuleList(members)
        # Not buffers: the mixture is rebuilt from its snapshots, never loaded from a state dict.
        self.weights = None if weights is None else torch.tensor(weights, dtype=torch.float64)
        # A fixed member per env row instead of a draw: every member valued in one batch (selection.py).
        self.assigned = assigned
        seen = dict.fromkeys(k for m in members for k in m.body.in_keys)
        self.in_keys = list({**seen, keys.IS_INIT: None, keys.MIXTURE_MEMBER: None})

    def forward(self, d: Entries) -> tuple:
        member = d[keys.MIXTURE_MEMBER].squeeze(-1)
        if member.dim() != 1:  # rows over time as well: every member on every row, then pick
            params = [m.params(d) for m in self.members]
            grid = torch.meshgrid(*[torch.arange(s, device=member.device) for s in member.shape], indexing="ij")
            return ({k: torch.stack([p[k] for p in params])[(member, *grid)] for k in params[0]},)
        # Each member on its own rows only: a valuation runs M members on M x E rows.
        out: dict[str, torch.Tensor] = {}
        n = member.shape[0]
        for i, m in enumerate(self.members):
            rows = (member == i).nonzero().squeeze(-1)
            if rows.numel() == 0:
                continue
            own = m.params({k: v[rows] if torch.is_tensor(v) and v.shape[:1] == (n,) else v for k, v in d.items()})
            for k, v in own.items():
                if k not in out:
                    out[k] = v.new_empty((n, *v.shape[1:]))
                out[k][rows] = v
        return (out,)

    def step(self, d: Entries) -> tuple[tuple, dict]:
        shape, device = d[keys.MIXTURE_MEMBER].shape, d[keys.MIXTURE_MEMBER].device
        if self.assigned is not None:
            fresh = self.assigned.view(shape).to(device)
        elif self.weights is None:
            fresh = torch.randint(len(self.members), shape, device=device)
        else:
            fresh = torch.multinomial(self.weights, shape.numel(), replacement=True).view(shape).to(device)
        member = torch.where(d[keys.IS_INIT], fresh, d[keys.MIXTURE_MEMBER])
        return self({**d, keys.MIXTURE_MEMBER: member}), {keys.MIXTURE_MEMBER: member}

    def initial_state(self, num_envs: int, device: torch.device) -> dict:
        return {keys.MIXTURE_MEMBER: torch.zeros(num_envs, 1, dtype=torch.long, device=device)}


def mixture_actor(
    members: list[Actor], weights: list[float] | None = None, assigned: torch.Tensor | None = None
) -> Actor:
    """An actor drawing one of ``members`` per episode (with ``weights``), or each row's ``assigned`` one."""
    # The body gives the chosen member's parameters; the distribution is the members' own (a bound method:
    # not a second registration of the member's head).
    head = nn.Identity()
    head.dist = members[0].head.dist
    return Actor(MixtureBody(members, weights, assigned), head)
