"""The agent every algorithm trains: an :class:`Actor` (a :class:`Body`, then a distribution head) and critics
keyed by signal (``keys.SIGNALS``), plain ``nn.Module``s on dicts of tensors; the heads
(``policy=mlp|lstm|gru|transformer``) differ only in their bodies and output networks (docs/architecture.md).
With K costs the ``"cost"`` critic is one network with K outputs, not K critics: downstream the cost is one
tensor with a trailing K, one pass values all, and K = 1 is the same network; the K values share hidden layers."""

from __future__ import annotations

from typing import Any, Mapping

import torch
from tensordict import TensorDictBase
from torch import distributions as D
from torch import nn

from cmdp_rl.policies.distributions import CategoricalHead, GaussianHead, action_outputs, make_action_head, sample
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.normalization import Normalizers

Entries = Mapping[Any, torch.Tensor]  # key -> tensor with leading batch dims

# Rows per critic call when valuing a whole batch: larger calls' activations leave the cache, and glibc
# hands blocks of several MB back to the OS on free and page-faults them in again.
CHUNK_ROWS = 8192


Features = tuple  # what a body gives the network after it: one tensor or several


class Body(nn.Module):
    """The part of an actor or critic that reads a step's entries and carries its history. ``in_keys``: what it
    reads, its state included; ``state_keys``: its state, whose next value :meth:`step` returns; ``recurrent``:
    trains on segments ``[B, L]`` in sequence (else any grouping of steps gives the same outputs)."""

    in_keys: list
    state_keys: tuple = ()
    recurrent: bool = False

    def forward(self, d: Entries) -> Features:
        """Features on training units (steps, or segments for a recurrent body)."""
        raise NotImplementedError

    def step(self, d: Entries) -> tuple[Features, dict]:
        """One acting step on ``[N, ...]`` entries: the features and the next state (key -> tensor)."""
        return self(d), {}

    def forward_with_state(self, d: Entries) -> tuple[Features, dict]:
        """:meth:`forward` and the state after each step (recurrent bodies; else none)."""
        return self(d), {}

    def initial_state(self, num_envs: int, device: torch.device) -> dict:
        """The state every episode starts from, ``[num_envs, ...]`` per key (zeros)."""
        return {}


class Actor(nn.Module):
    """body -> distribution head (its output network, then the distribution's parameters)."""

    def __init__(self, body: Body, head: GaussianHead | CategoricalHead) -> None:
        super().__init__()
        self.body = body
        self.head = head

    def params(self, d: Entries) -> dict[str, torch.Tensor]:
        return self.head(*self.body(d))

    def dist(self, d: Entries) -> D.Distribution:
        return self.head.dist(self.params(d))


class Critic(nn.Module):
    """body -> output network -> value ``[..., 1]`` (the cost critic: ``[..., K]``)."""

    def __init__(self, body: Body, net: nn.Module) -> None:
        super().__init__()
        self.body = body
        self.net = net

    def forward(self, d: Entries) -> torch.Tensor:
        return self.net(*self.body(d))

    def step(self, d: Entries) -> torch.Tensor:
        return self.net(*self.body.step(d)[0])


class Agent(nn.Module):
    """Actor, critics keyed by signal and the normalization statistics they use. ``segment_length``: steps per
    training segment of a recurrent agent (0: the whole row); ``cost_names``: the cost critic's K outputs."""

    def __init__(
        self,
        actor: Actor,
        critics: Mapping[str, Critic],
        normalizers: Normalizers | None = None,
        segment_length: int = 0,
        cost_names: tuple[str, ...] = ("cost_0",),
    ) -> None:
        super().__init__()
        self.cost_names = tuple(cost_names)
        self.actor = actor
        self.critics = nn.ModuleDict(dict(critics))
        self.normalizers = normalizers if normalizers is not None else Normalizers()
        self.segment_length = segment_length

    @property
    def num_costs(self) -> int:
        return len(self.cost_names)

    @property
    def recurrent(self) -> bool:
        return self.actor.body.recurrent or any(c.body.recurrent for c in self.critics.values())

    @property
    def in_keys(self) -> list:
        """Every root entry the actor or a critic reads, each once, in order of first use."""
        bodies = [self.actor.body, *(c.body for c in self.critics.values())]
        return list(dict.fromkeys(k for body in bodies for k in body.in_keys))

    def _stepped(self) -> list[tuple[str | None, Body]]:
        """The bodies :meth:`act` steps: the actor's and those of critics with a state (re-run from it)."""
        critics = [(name, c.body) for name, c in self.critics.items() if c.body.recurrent]
        return [(None, self.actor.body), *critics]

    def initial_state(self, num_envs: int, device: torch.device | str = "cpu") -> dict:
        device = torch.device(device)
        return {k: v for _, body in self._stepped() for k, v in body.initial_state(num_envs, device).items()}

    @torch.no_grad()
    def act(self, d: Entries, deterministic: bool = False) -> dict:
        """One step: the distribution's parameters, the action (the mode if ``deterministic``), its log-prob
        and each carried state's next value under ``("next", key)``."""
        out: dict = {}
        for name, body in self._stepped():
            features, state = body.step(d)
            out.update({(keys.NEXT, k): v for k, v in state.items()})
            if name is None:
                out.update(self.actor.head(*features))
        if isinstance(self.actor.head, GaussianHead):  # the same numbers without the distribution object
            out[keys.ACTION], out[keys.LOG_PROB] = self.actor.head.act(out, deterministic)
            return out
        dist = self.actor.head.dist(out)
        out[keys.ACTION] = sample(dist, deterministic)
        out[keys.LOG_PROB] = dist.log_prob(out[keys.ACTION])
        return out

    def dist(self, units: Entries) -> D.Distribution:
        """The action distribution on training units."""
        return self.actor.dist(units)

    def value(self, signal: str, units: Entries) -> torch.Tensor:
        """The ``signal`` critic's value ``[..., 1]`` on training units."""
        return self.critics[signal](units)

    def training_units(self, data: Mapping[Any, torch.Tensor]) -> dict:
        """A ``[N, T, ...]`` batch as steps ``[N T, ...]``, or a recurrent agent's segments ``[N T / L, L, ...]``."""
        if not self.recurrent:
            return {k: v.flatten(0, 1) for k, v in data.items()}
        out = {}
        for k, v in data.items():
            T = v.shape[1]
            L = self.segment_length if 0 < self.segment_length < T else T
            out[k] = v.unflatten(1, (T // L, L)).flatten(0, 1)
        return out

    @torch.no_grad()
    def rollout_values(self, batch: TensorDictBase, signal: str) -> tuple[torch.Tensor, torch.Tensor]:
        """``(V(obs), V(next obs))`` of the ``signal`` critic on a collector batch ``[N, T]``, each ``[N, T, 1]``.

        ``V(next obs)`` is the following step's ``V(obs)`` except at episode ends and the last step, where it is one
        more step of the critic from the state it reached, without a reset: ``V(final obs)`` then conditions on the
        episode's history (torchrl's shifted GAE would read the next episode's reset observation). A recurrent
        critic's values are one pass over each row from its stored state, restarting at every ``is_init``."""
        critic = self.critics[signal]
        body = critic.body
        N, T = batch.shape
        fresh = batch.get((keys.NEXT, keys.DONE)).squeeze(-1).clone()
        fresh[:, -1] = True
        entries = {k: batch.get(k) for k in body.in_keys}
        if body.recurrent:
            features, after = body.forward_with_state(entries)
            values = critic.net(*features)
        else:  # a function of each step's own entries: value the steps in chunks
            values = _chunked(critic, {k: v.flatten(0, 1) for k, v in entries.items()}).unflatten(0, (N, T))
            after = {}
        next_values = torch.empty_like(values)
        next_values[:, :-1] = values[:, 1:]
        # The inputs one step on: the next observation, this step's action and cost, the state after it.
        nxt = {
            k: (after[k] if k in after else batch.get((keys.NEXT, k)))[fresh] for k in body.in_keys if k != keys.IS_INIT
        }
        if keys.IS_INIT in body.in_keys:
            nxt[keys.IS_INIT] = torch.zeros(int(fresh.sum()), 1, dtype=torch.bool, device=batch.device)
        next_values[fresh] = critic.step(nxt) if body.recurrent else _chunked(critic, nxt)
        return values, next_values


def critic_outputs(signal: str, env: Any) -> int:
    """Outputs of the ``signal`` critic: one value for the reward, one per constraint for the cost."""
    return getattr(env, "num_costs", 1) if signal == "cost" else 1


def actor_and_critics(env: Any, normalizers: Normalizers, init_log_std: float, network: Any, **kwargs: Any) -> Agent:
    """The agent of a policy head: ``network(role, outputs, out_gain) -> (body, output net)`` for the actor
    (``role`` "actor", gain 0.01) and the reward and cost critics (gain 1), built in that order."""
    body, net = network("actor", action_outputs(env.action_space), 0.01)
    actor = Actor(body, make_action_head(env.action_space, net, init_log_std))
    critics = {signal: Critic(*network(signal, critic_outputs(signal, env), 1.0)) for signal in ("reward", "cost")}
    return Agent(actor, critics, normalizers, cost_names=env.cost_names, **kwargs)


def _chunked(critic: Critic, flat: dict) -> torch.Tensor:
    rows = next(iter(flat.values())).shape[0]
    if rows <= CHUNK_ROWS:
        return critic(flat)
    parts = [{k: v[i : i + CHUNK_ROWS] for k, v in flat.items()} for i in range(0, rows, CHUNK_ROWS)]
    return torch.cat([critic(p) for p in parts])


def make_agent(cfg: Any, env: Any, normalizers: Normalizers | None = None, algo: Any = None) -> Agent:
    """The agent ``policy=<cfg.name>`` builds for ``env`` (behind ``normalizers``' observation normalizer), or,
    given ``algo``'s options, the one it trains (``AlgoConfig.shape_agent``)."""
    from cmdp_rl.config.registry import component  # the registry imports the policy modules, which import this one

    agent = component("policy", cfg.name).build(cfg, env, normalizers if normalizers is not None else Normalizers())
    agent = agent.to(env.device)
    return agent if algo is None else algo.shape_agent(agent)
