"""The one rollout collector every algorithm shares.

It steps a :class:`~cmdp_rl.envs.VecEnv` with a TensorDict policy and returns one ``[num_envs, T]``
TensorDict in torchrl's layout, reward and cost side by side under ``"next"``, with the running
undiscounted episode return and cost written on every step.

Why not torchrl's ``Collector``: it costs about 1.3 ms per step here (measured, see
``../shared/notes``), more than stepping eight Reach1D envs; this loop does only what the batch
needs. It keeps torchrl's conventions (``is_init``, ``"next"``, exploration type), so torchrl's GAE,
losses and recurrent modules read its output unchanged.

Per step it handles plain tensors: each step's entries are kept in a dict and stacked into the
batch once at the end. A stateless probabilistic actor (the MLP policy) runs on tensors too
(:class:`~cmdp_rl.policies.tensor_path.TensorActor`, same numbers), and so do the stateful ones
built of torchrl's recurrent modules and plain modules (``StepProgram``); any other policy is
called on a TensorDict.

History-dependent policies (policies/recurrent.py, transformer.py) get, as torchrl's env transforms
would give them: their initial state at the root (from torchrl's ``make_tensordict_primer``, via
``get_primers_from_module``: zeros), the state they write under ``"next"`` carried to the next
step and reset to the initial state where an episode ended (as ``TensorDictPrimer`` does on
reset), and, if their ``in_keys`` ask, the previous step's action and cost (``keys.PREV_ACTION``,
``keys.PREV_COST``; zero at an episode's first step; under ``"next"``, this step's).
"""

from __future__ import annotations

from typing import Any, Callable

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.transforms import Compose
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules.utils import get_primers_from_module

from cmdp_rl import keys
from cmdp_rl.envs import VecEnv
from cmdp_rl.policies.tensor_path import StepProgram, TensorActor

Entries = dict  # key (a string, or a tuple for a nested key) -> tensor of one step, batch [N]


def initial_state(policy: TensorDictModuleBase, num_envs: int, device: torch.device) -> Entries:
    """The recurrent state ``policy`` starts every episode from, ``[num_envs, ...]`` per key: the
    default values of the primers torchrl's ``make_tensordict_primer`` gives for its submodules
    (none for a stateless policy)."""
    if not isinstance(policy, torch.nn.Module):  # a plain function of TensorDicts: no state
        return {}
    primer = get_primers_from_module(policy, warn=False)
    if primer is None:
        return {}
    primers = list(primer.transforms) if isinstance(primer, Compose) else [primer]
    state: Entries = {}
    for p in primers:
        zeros = p.primers.expand(num_envs).zero().to(device)
        for key, value in zeros.items(include_nested=True, leaves_only=True):
            default = p.default_value.get(key, 0.0) if isinstance(p.default_value, dict) else p.default_value
            if callable(default) or default != 0:
                raise ValueError(f"policy: primer {key!r} has a non-zero default {default!r}; only zero initial states are supported")
            state[key] = value
    return state


class PolicyMemory:
    """What a policy carries from one step to the next besides the observation, for N envs: its
    initial state (:func:`initial_state`), the state it writes under ``"next"`` (reset to the
    initial one where an episode ended, as torchrl's ``TensorDictPrimer`` does on reset), and the
    previous action and cost if its ``in_keys`` ask for them. Used by the collector and by
    ``replay.py``, which steps one plain env."""

    def __init__(self, policy: TensorDictModuleBase, num_envs: int, action_dim: int, device: torch.device) -> None:
        self.initial = initial_state(policy, num_envs, device)
        in_keys = getattr(policy, "in_keys", ())
        self.prev_action = keys.PREV_ACTION in in_keys
        self.prev_cost = keys.PREV_COST in in_keys
        self.num_envs, self.action_dim, self.device = num_envs, action_dim, device

    def start(self) -> Entries:
        """The root entries of every env's first step (besides observation and ``is_init``)."""
        root = dict(self.initial)
        if self.prev_action:
            root[keys.PREV_ACTION] = torch.zeros(self.num_envs, self.action_dim, device=self.device)
        if self.prev_cost:
            root[keys.PREV_COST] = torch.zeros(self.num_envs, 1, device=self.device)
        return root

    def step(self, out: Entries, cost: torch.Tensor, done: torch.Tensor) -> tuple[Entries, Entries]:
        """After a step: (the previous action/cost to store under ``"next"``: this step's; the root
        entries of the next step). ``out``: what the policy wrote; ``done``: ``[N, 1]``."""
        carried = {k[1]: v for k, v in out.items() if isinstance(k, tuple) and k[0] == keys.NEXT}
        history = {}
        if self.prev_action:
            history[keys.PREV_ACTION] = out[keys.ACTION]
        if self.prev_cost:
            history[keys.PREV_COST] = cost
        if not (carried or history):
            return {}, {}
        # A new episode starts from the initial state, without history.
        root = {k: _reset_where(done, v, self.initial.get(k)) for k, v in carried.items()}
        root.update({k: v.masked_fill(done, 0) for k, v in history.items()})
        return {(keys.NEXT, k): v for k, v in history.items()}, root


def _td_policy(policy: TensorDictModuleBase, batch_size: int, device: torch.device) -> Callable[[Entries], Entries]:
    """Any TensorDict policy as a function of step entries; keys it writes under ``"next"`` (a
    recurrent state) come back as ``("next", key)``."""

    def act(inputs: Entries) -> Entries:
        td = policy(TensorDict(inputs, batch_size=[batch_size], device=device))
        return dict(td.items(include_nested=True, leaves_only=True))

    return act


class Collector:
    """Collects ``rollout_steps`` steps from every env of ``env`` per call to :meth:`collect`.

    Episodes run on across calls; the env is reset once, at construction, with ``seed``. Actions
    are sampled (``ExplorationType.RANDOM``) unless ``exploration`` says otherwise.
    Keys a policy writes under ``"next"`` (a recurrent state) are carried to the next step's root.
    ``tensor_path=False`` forces the TensorDict call of the policy (for comparison).
    """

    def __init__(
        self,
        env: VecEnv,
        policy: TensorDictModuleBase,
        rollout_steps: int,
        seed: int | None = None,
        exploration: ExplorationType = ExplorationType.RANDOM,
        tensor_path: bool = True,
    ) -> None:
        self.env = env
        self.exploration = exploration
        self.policy = policy
        self.rollout_steps = rollout_steps
        n, dev = env.num_envs, env.device
        fast = (TensorActor.wrap(policy) or StepProgram.wrap(policy)) if tensor_path else None
        self._act = fast if fast is not None else _td_policy(policy, n, dev)
        self._memory = PolicyMemory(policy, n, env.action_dim, dev)
        self._root: Entries = {
            **self._memory.start(), keys.OBS: env.reset(seed=seed),
            keys.IS_INIT: torch.ones(n, 1, dtype=torch.bool, device=dev),
        }
        self._ep_return = torch.zeros(n, 1, device=dev)
        self._ep_cost = torch.zeros(n, 1, device=dev)
        self._ep_length = torch.zeros(n, 1, dtype=torch.int64, device=dev)
        self.total_steps = 0
        self.total_cost = 0.0  # every cost collected so far: the numerator of the cost rate

    @torch.no_grad()
    def collect(self) -> TensorDictBase:
        steps: list[Entries] = []
        root = self._root
        ep_return, ep_cost, ep_length = self._ep_return, self._ep_cost, self._ep_length
        with set_exploration_type(self.exploration):
            for _ in range(self.rollout_steps):
                out = self._act(root)
                step = self.env.step(out[keys.ACTION])
                done = step.terminated | step.truncated
                ep_return = ep_return + step.reward
                ep_cost = ep_cost + step.cost
                ep_length = ep_length + 1
                history, carried = self._memory.step(out, step.cost, done)
                steps.append({
                    **root, **out, **history,
                    (keys.NEXT, keys.OBS): step.next_obs,
                    (keys.NEXT, keys.REWARD): step.reward,
                    (keys.NEXT, keys.COST): step.cost,
                    (keys.NEXT, keys.TERMINATED): step.terminated,
                    (keys.NEXT, keys.TRUNCATED): step.truncated,
                    (keys.NEXT, keys.DONE): done,
                    (keys.NEXT, keys.EPISODE_RETURN): ep_return,
                    (keys.NEXT, keys.EPISODE_COST): ep_cost,
                    (keys.NEXT, keys.EPISODE_LENGTH): ep_length,
                })
                ep_return = ep_return.masked_fill(done, 0.0)
                ep_cost = ep_cost.masked_fill(done, 0.0)
                ep_length = ep_length.masked_fill(done, 0)
                root = {**carried, keys.OBS: step.obs, keys.IS_INIT: done}
        self._root = root
        self._ep_return, self._ep_cost, self._ep_length = ep_return, ep_cost, ep_length
        self.total_steps += self.rollout_steps * self.env.num_envs
        n = self.env.num_envs
        batch = TensorDict(
            {k: torch.stack([s[k] for s in steps], dim=1) for k in steps[0]},
            batch_size=[n, self.rollout_steps], device=self.env.device,
        )
        self.total_cost += batch.get((keys.NEXT, keys.COST)).sum().item()
        return batch

    def state_dict(self) -> dict[str, Any]:
        """Where the rollout stands: the next root (observation, ``is_init``, carried recurrent
        state), the running episode sums, the step and cost counters, and the env's own state. A collector
        built anew on the same config and given this continues the same trajectories."""
        return {
            "root": dict(self._root),
            "episode_return": self._ep_return.clone(),
            "episode_cost": self._ep_cost.clone(),
            "episode_length": self._ep_length.clone(),
            "total_steps": self.total_steps,
            "total_cost": self.total_cost,
            "env": self.env.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.env.load_state_dict(state["env"])
        dev = self.env.device
        self._root = {k: v.to(dev) for k, v in state["root"].items()}
        self._ep_return = state["episode_return"].to(dev).clone()
        self._ep_cost = state["episode_cost"].to(dev).clone()
        self._ep_length = state["episode_length"].to(dev).clone()
        self.total_steps = int(state["total_steps"])
        self.total_cost = float(state["total_cost"])


def _reset_where(done: torch.Tensor, value: torch.Tensor, initial: torch.Tensor | None) -> torch.Tensor:
    """``value`` with the rows of envs whose episode ended (``done``: ``[N, 1]``) set to ``initial``."""
    where = done.view(done.shape[0], *([1] * (value.dim() - 1)))
    return torch.where(where, torch.zeros_like(value) if initial is None else initial, value)


def finished_episodes(batch: TensorDictBase) -> dict[str, torch.Tensor]:
    """Undiscounted return, cost and length of every episode that ended inside ``batch``."""
    done = batch.get((keys.NEXT, keys.DONE)).squeeze(-1)
    return {
        name: batch.get((keys.NEXT, key)).squeeze(-1)[done].float()
        for name, key in (
            ("return", keys.EPISODE_RETURN), ("cost", keys.EPISODE_COST), ("length", keys.EPISODE_LENGTH)
        )
    }
