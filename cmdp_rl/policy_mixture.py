"""The deployed policy of ``final_policy: mixture``: a uniform mixture of snapshots of the actor
taken over the last ``average_last`` fraction of the iterations (at most ``mixture_size`` of
them), one snapshot drawn per EPISODE and followed until the episode ends.

Why a mixture drawn per episode: the guarantees of primal-dual (Lagrangian) methods are for the
average of the iterates' occupancy measures, and a policy that draws iterate i with probability
1/M at the start of an episode and follows it has exactly that occupancy, so its expected return
and costs are the mean of the iterates' (Le, Voloshin, Yue, "Batch policy learning under
constraints", ICML 2019, Sec. 3-4: the returned policy is the uniform mixture of the iterates;
Calvo-Fullana, Paternain, Ribeiro, Chamon, IEEE TAC 2023, Sec. III: the last iterate of a
primal-dual method need not be feasible, its iterates' mixture is). Drawing per step instead would
mix the actions, which is a different (and generally not averaged) policy. A parameter average
(``policy_average.py``) is one network, but near a randomised optimum it is a policy between the
iterates, not their mixture.

The draw is a carried state of the actor's body (``keys.MIXTURE_MEMBER``): on an episode's first
step (``is_init``) each env row draws a member from torch's generator (the evaluation seeds it) and
keeps it until its episode ends, as a recurrent state is kept. So the collector, the evaluation,
``evaluate.py``, the Reach1D plot and the video run a mixture unchanged. Its members are memoryless
actors (``policy=mlp``; config.py refuses the others, whose own states would collide).
"""

from __future__ import annotations

import copy
import math

import torch
from torch import nn

from cmdp_rl import keys
from cmdp_rl.policies.agent import Actor, Agent, Body, Entries


class IterateSnapshots:
    """Copies of the actor's state taken every ``stride`` iterations, ending with the last: with a
    window of W iterations and at most ``size`` members, ``stride = ceil(W / size)``. Its state is
    plain tensors and ints, so a checkpoint with it loads with ``torch.load(weights_only=True)``."""

    def __init__(self, first_iteration: int, iterations: int, size: int) -> None:
        self.first_iteration, self.iterations = first_iteration, iterations
        self.stride = math.ceil((iterations - first_iteration + 1) / size)
        self.taken: list[int] = []
        self.members: list[dict[str, torch.Tensor]] = []

    @property
    def count(self) -> int:
        return len(self.members)

    def wants(self, iteration: int) -> bool:
        return iteration >= self.first_iteration and (self.iterations - iteration) % self.stride == 0

    @torch.no_grad()
    def update(self, module: nn.Module, iteration: int) -> None:
        self.taken.append(iteration)
        self.members.append({k: v.detach().clone() for k, v in module.state_dict().items()})

    def matches(self, state: dict) -> bool:
        """Whether a saved state was taken on this window and stride (a resume may have moved them)."""
        return (state["first_iteration"], state["stride"]) == (self.first_iteration, self.stride)

    def state_dict(self) -> dict:
        return {
            "first_iteration": self.first_iteration,
            "stride": self.stride,
            "taken": list(self.taken),
            "members": [{k: v.clone() for k, v in m.items()} for m in self.members],
        }

    def load_state_dict(self, state: dict) -> None:
        self.taken = [int(i) for i in state["taken"]]
        self.members = [{k: v.clone() for k, v in m.items()} for m in state["members"]]

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
        if self.members:
            agent.actor = mixture_actor(self.actors(agent.actor))


class MixtureBody(Body):
    """Runs every member actor on the step and keeps, per row, the distribution parameters of the
    row's member (``keys.MIXTURE_MEMBER``, drawn afresh where ``is_init``)."""

    state_keys = (keys.MIXTURE_MEMBER,)

    def __init__(self, members: list[Actor]) -> None:
        super().__init__()
        if any(m.body.recurrent or m.body.state_keys for m in members):
            raise ValueError("a mixture's members must be memoryless actors (policy=mlp)")
        self.members = nn.ModuleList(members)
        seen = dict.fromkeys(k for m in members for k in m.body.in_keys)
        self.in_keys = list({**seen, keys.IS_INIT: None, keys.MIXTURE_MEMBER: None})

    def forward(self, d: Entries) -> tuple:
        member = d[keys.MIXTURE_MEMBER].squeeze(-1)
        params = [m.params(d) for m in self.members]
        rows = torch.arange(member.shape[0], device=member.device)
        return ({k: torch.stack([p[k] for p in params])[member, rows] for k in params[0]},)

    def step(self, d: Entries) -> tuple[tuple, dict]:
        fresh = torch.randint(len(self.members), d[keys.MIXTURE_MEMBER].shape, device=d[keys.MIXTURE_MEMBER].device)
        member = torch.where(d[keys.IS_INIT], fresh, d[keys.MIXTURE_MEMBER])
        return self({**d, keys.MIXTURE_MEMBER: member}), {keys.MIXTURE_MEMBER: member}

    def initial_state(self, num_envs: int, device: torch.device) -> dict:
        return {keys.MIXTURE_MEMBER: torch.zeros(num_envs, 1, dtype=torch.long, device=device)}


class _Chosen(nn.Module):
    """The mixture's head: the body already gives the chosen member's parameters; their
    distribution is the members' own (every member has the same head)."""

    def __init__(self, head: nn.Module) -> None:
        super().__init__()
        self._dist = head.dist  # a bound method, not a second registration of the member's head

    def forward(self, params: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return params

    def dist(self, params: dict[str, torch.Tensor]) -> torch.distributions.Distribution:
        return self._dist(params)


def mixture_actor(members: list[Actor]) -> Actor:
    """An actor that draws one of ``members`` per episode (uniformly) and follows it."""
    return Actor(MixtureBody(members), _Chosen(members[0].head))


def members_of(actor: Actor) -> list[Actor]:
    """The member actors of a mixture; any other actor is its own one member."""
    return list(actor.body.members) if isinstance(actor.body, MixtureBody) else [actor]


__all__ = ["IterateSnapshots", "MixtureBody", "members_of", "mixture_actor"]
