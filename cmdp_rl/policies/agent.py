"""The agent every algorithm trains: an actor and a bank of critics keyed by signal.

- :class:`Actor`: a network (:class:`Body`) whose output a distribution head
  (``policies/distributions.py``, chosen from the env's action space) turns into the action
  distribution's parameters.
- ``critics``: an ``nn.ModuleDict`` of :class:`Critic` keyed by signal, ``"reward"`` and
  ``"cost"`` (``keys.SIGNALS`` names their entries in a batch); a Q-critic is one more entry.

Several constraints (an env reporting K costs): the ``"cost"`` critic is one network with K outputs,
``[..., K]``, one value per constraint, not K critics in the bank. Why: every layer downstream keeps
the cost as one tensor with a trailing K (the collector's sums, GAE batched over K, the scalers,
the multipliers' advantage ``sum_k lambda_k A_c,k``), one forward pass values all constraints, a
recurrent cost critic keeps one state, and K = 1 is exactly the network it was before (same
parameters, same initialisation, same checkpoint keys). What it gives up: the K values share their
hidden layers; costs that need unrelated features could learn more slowly than with K networks.

All of it is plain ``nn.Module``s on dicts of tensors (root keys of a batch, as in ``keys.py``).
The policy heads (``policy=mlp|lstm|gru|transformer``) differ only in their networks: the
:class:`Body` (what it reads, what state it carries from one step to the next, whether it trains on
single steps or on segments of consecutive steps) and the stateless output network after it.

Two modes, one computation:

- acting (:meth:`Agent.act`, the collector): one step of N envs, ``[N, ...]`` entries; a body with
  memory reads its state at the root and returns the next one, which the agent returns under
  ``("next", key)`` and the collector carries to the next step (``collector.PolicyMemory``);
- training (:meth:`Agent.dist`, :meth:`Agent.value`): training units, single steps ``[B, ...]``
  or, for recurrent bodies, segments ``[B, L, ...]`` (:meth:`Agent.training_units`), run from the
  state stored at each segment's first step.
"""

from __future__ import annotations

from typing import Any, Mapping

import torch
from tensordict import TensorDictBase
from torch import distributions as D
from torch import nn

from cmdp_rl.policies.distributions import CategoricalHead, GaussianHead, sample
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.normalization import Normalizers

Entries = Mapping[Any, torch.Tensor]  # key -> tensor with leading batch dims

# Rows per critic call when valuing a whole batch. Larger calls were slower per row here: their
# activations leave the cache, and glibc hands blocks of several MB back to the OS on free and
# page-faults them in again.
CHUNK_ROWS = 8192


Features = tuple  # what a body gives the network after it: one tensor or several


class Body(nn.Module):
    """The part of an actor or a critic that reads the step's entries and carries its history:
    nothing but the input encoding for the MLP, the LSTM/GRU for the recurrent heads, the window of
    the last K steps for the transformer. What follows it (the output network) is a stateless
    function of its features.

    ``in_keys``: the root entries it reads (its own carried state included); ``state_keys``: the
    entries of its state, which :meth:`step` returns the next value of; ``recurrent``: trains on
    segments ``[B, L]`` run in sequence (else any grouping of steps gives the same outputs).
    """

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
    """Actor, critics keyed by signal, and the normalization statistics they use (no parameters;
    saved with them, see ``normalization.py``). ``segment_length``: steps per training segment of
    a recurrent agent (0, or not shorter than the rollout: the whole rollout row). ``cost_names``:
    the env's K costs, which the cost critic's K outputs value in that order."""

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

    # --- what the agent reads and carries ------------------------------------------------------
    @property
    def recurrent(self) -> bool:
        return self.actor.body.recurrent or any(c.body.recurrent for c in self.critics.values())

    @property
    def in_keys(self) -> list:
        """Every root entry the actor or a critic reads, each once, in order of first use."""
        seen: dict = {}
        for body in self._bodies():
            seen.update(dict.fromkeys(body.in_keys))
        return list(seen)

    def _bodies(self) -> list[Body]:
        return [self.actor.body, *(c.body for c in self.critics.values())]

    def _stepped(self) -> list[tuple[str | None, Body]]:
        """The networks :meth:`act` steps: the actor, and critics with a state of their own (their
        state at every step must be in the batch: a segment is re-run from its stored state)."""
        critics = [(name, c.body) for name, c in self.critics.items() if c.body.recurrent]
        return [(None, self.actor.body), *critics]

    def initial_state(self, num_envs: int, device: torch.device | str = "cpu") -> dict:
        state: dict = {}
        for _, body in self._stepped():
            state.update(body.initial_state(num_envs, torch.device(device)))
        return state

    # --- acting ----------------------------------------------------------------------------------
    @torch.no_grad()
    def act(self, d: Entries, deterministic: bool = False) -> dict:
        """One step: the distribution's parameters, the action (sampled, or the mode if
        ``deterministic``) and its log-prob, and every carried state's next value under
        ``("next", key)``."""
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
        action = sample(dist, deterministic)
        out[keys.ACTION] = action
        out[keys.LOG_PROB] = dist.log_prob(action)
        return out

    # --- training --------------------------------------------------------------------------------
    def dist(self, units: Entries) -> D.Distribution:
        """The action distribution on training units."""
        return self.actor.dist(units)

    def value(self, signal: str, units: Entries) -> torch.Tensor:
        """The ``signal`` critic's value ``[..., 1]`` on training units."""
        return self.critics[signal](units)

    def training_units(self, data: Mapping[Any, torch.Tensor]) -> dict:
        """Entries of a ``[N, T, ...]`` batch as training units ``[U, ...]``: steps (``U = N T``) or,
        for a recurrent agent, segments ``[U, L, ...]`` with ``U = N T / L``, never single steps."""
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
        """The ``signal`` critic's values of the observations and of the next observations of a
        collector batch ``[N, T]``: ``(V(obs), V(next obs))``, each ``[N, T, 1]``.

        A step's next observation is the following step's observation unless the episode ended
        there (then it is the final one, and the following step starts from a reset one), so
        ``V(next obs)`` is the following step's ``V(obs)`` except at episode ends and on the last
        step ("fresh" steps), where it is computed. This halves the critic work of GAE, and for a
        critic with memory it is also what makes the values consistent:

        - Root values: one pass over the batch; a recurrent critic runs each row from its state
          stored at the row's first step, restarting from the stored (zero) state at every episode
          start (``is_init``): exactly the values it gives stepping through the rollout.
        - Next values at fresh steps: one more step of the critic from the state it reached after
          the step (a recurrent pass's own next state; a transformer's window from the batch), on
          the next observation and this step's action and cost, without a reset. ``V(final obs)``
          thus conditions on the episode's whole history, which a truncated episode bootstraps from.

        (torchrl's ``GAE(..., shifted=True)`` on a recurrent critic would take ``V(next obs)`` at an
        episode end from the row's next step, the next episode's reset observation: wrong for a
        truncated episode's bootstrap.)
        """
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
        # The inputs one step on, at the fresh steps: the next observation, this step's action and
        # cost as "previous", the state after this step.
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


def _chunked(critic: Critic, flat: dict) -> torch.Tensor:
    rows = next(iter(flat.values())).shape[0]
    if rows <= CHUNK_ROWS:
        return critic(flat)
    parts = [{k: v[i : i + CHUNK_ROWS] for k, v in flat.items()} for i in range(0, rows, CHUNK_ROWS)]
    return torch.cat([critic(p) for p in parts])


def make_agent(cfg: Any, env: Any, normalizers: Normalizers | None = None, algo: Any = None) -> Agent:
    """The agent ``policy=<cfg.name>`` builds for ``env`` (its observation and action spaces);
    ``normalizers``' observation normalizer, if any, goes in front of every network. ``algo``: the
    algorithm's options; the agent is then the one it trains (``AlgoConfig.shape_agent``)."""
    from cmdp_rl.config.registry import component  # the registry imports the policy modules, which import this one

    agent = component("policy", cfg.name).build(cfg, env, normalizers if normalizers is not None else Normalizers())
    agent = agent.to(env.device)
    return agent if algo is None else algo.shape_agent(agent)


__all__ = ["Actor", "Agent", "Body", "CHUNK_ROWS", "Critic", "critic_outputs", "make_agent"]
