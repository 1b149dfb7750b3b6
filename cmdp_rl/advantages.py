"""Twin critics, twin GAEs: advantages and value targets for reward and for cost.

Both GAEs are torchrl's, reading values the critics wrote beforehand (``value_network=None``), so
one critic pass serves both the estimate and the logging. A truncated step (time limit) is not
terminal: GAE bootstraps from ``V(next observation)`` unless ``("next", "terminated")`` is set,
for the reward critic and the cost critic alike.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.modules import set_recurrent_mode
from torchrl.objectives.value import GAE

from cmdp_rl import keys
from cmdp_rl.policies import ActorCritic
from cmdp_rl.policies.tensor_path import TensorModule

# Rows per critic call. Larger calls were slower per row here: their activations leave the cache,
# and glibc hands blocks of several MB back to the OS on free and page-faults them in again.
CHUNK_ROWS = 8192


def _chunked(net: torch.nn.Module, x: torch.Tensor) -> torch.Tensor:
    if x.shape[0] <= CHUNK_ROWS:
        return net(x)
    return torch.cat([net(part) for part in x.split(CHUNK_ROWS)])


def write_values(batch: TensorDictBase, critic: TensorDictModuleBase, ac: ActorCritic | None = None) -> None:
    """Write ``critic``'s values of the observations and of the next observations of a
    collector batch ``[N, T]`` (at the root and under ``"next"``).

    A step's next observation is the following step's observation unless the episode ended there
    (then it is the final one, and the following step starts from a reset one), so ``V(next obs)``
    is the following step's ``V(obs)`` except at episode ends and on the last step ("fresh" steps),
    where it is computed. This halves the critic work of GAE, and for a critic with memory it is
    also what makes the values consistent:

    - Root values: one pass over the batch, in recurrent mode for a recurrent critic (``ac``
      says): each row is run from the critic state stored at its first step, restarting from the
      stored (zero) state at every episode start (``is_init``). These are exactly the values the
      critic gives stepping through the rollout, with the current parameters.
    - Next values at fresh steps: one more step of the critic, from the state it reached after
      the step (the pass's own ``("next", state)``, which torchrl's recurrent mode writes at the
      end of each trajectory piece, i.e. exactly at the fresh steps; a transformer's window from
      the batch), on the next observation and this step's action and cost, without a reset.
      ``V(final obs)`` thus conditions on the episode's whole history, which a truncated episode
      bootstraps from.

    Why not torchrl's ``GAE(..., shifted=True)`` on a recurrent critic (the stack notes): it takes
    ``V(next obs)`` at an episode end from the row's next step, i.e. from the reset observation of
    the next episode, which is wrong for a truncated episode's bootstrap; and its
    ``deactivate_vmap`` path replays the next sequence with another history (off by up to 1.7e-2).
    """
    fast = TensorModule.wrap(critic)
    key = critic.out_keys[0]
    fresh = batch.get((keys.NEXT, keys.DONE)).squeeze(-1).clone()
    fresh[:, -1] = True
    if fast is not None and fast.in_keys == [keys.OBS]:
        # A memoryless critic of the observation: plain tensors, in chunks.
        obs = batch.get(keys.OBS)
        values = _chunked(fast.net, obs.flatten(0, 1)).unflatten(0, obs.shape[:2])
        next_values = torch.empty_like(values)
        next_values[:, :-1] = values[:, 1:]
        next_values[fresh] = _chunked(fast.net, batch.get((keys.NEXT, keys.OBS))[fresh])
        batch.set(key, values)
        batch.set((keys.NEXT, key), next_values)
        return
    recurrent = ac is not None and ac.recurrent
    inputs = batch.select(*critic.in_keys)
    if recurrent:
        with ac.sequence_mode():
            out = critic(inputs)
    else:  # a function of each step's own entries: any grouping of steps gives the same values
        flat = inputs.reshape(-1)
        out = torch.cat([critic(part) for part in flat.split(CHUNK_ROWS)]).reshape(batch.shape)
    values = out.get(key)
    next_values = torch.empty_like(values)
    next_values[:, :-1] = values[:, 1:]
    # The critic's inputs one step on, at the fresh steps: the next observation, this step's
    # action and cost as "previous", the state after this step (the pass's own where it wrote one).
    nxt = {}
    for k in critic.in_keys:
        if k == keys.IS_INIT:
            continue
        source = out if (keys.NEXT, k) in out.keys(True) else batch
        nxt[k] = source.get((keys.NEXT, k))[fresh]
    n_fresh = int(fresh.sum())
    nxt[keys.IS_INIT] = torch.zeros(n_fresh, 1, dtype=torch.bool, device=batch.device)
    with set_recurrent_mode(False):
        next_values[fresh] = critic(TensorDict(nxt, batch_size=[n_fresh], device=batch.device)).get(key)
    batch.set(key, values)
    batch.set((keys.NEXT, key), next_values)


class TwinGAE:
    def __init__(self, gamma: float, cost_gamma: float, lmbda: float) -> None:
        self.reward = GAE(gamma=gamma, lmbda=lmbda, value_network=None)
        self.reward.set_keys(
            reward=keys.REWARD, value=keys.VALUE, advantage=keys.ADVANTAGE, value_target=keys.VALUE_TARGET,
            done=keys.DONE, terminated=keys.TERMINATED,
        )
        self.cost = GAE(gamma=cost_gamma, lmbda=lmbda, value_network=None)
        self.cost.set_keys(
            reward=keys.COST, value=keys.COST_VALUE, advantage=keys.COST_ADVANTAGE,
            value_target=keys.COST_VALUE_TARGET, done=keys.DONE, terminated=keys.TERMINATED,
        )

    @torch.no_grad()
    def __call__(self, batch: TensorDictBase, ac: ActorCritic) -> TensorDictBase:
        """Write values, advantages and value targets of both critics of ``ac`` into ``batch`` ([N, T])."""
        for module in (ac.critic, ac.cost_critic):
            write_values(batch, module, ac)
        self.reward(batch)
        self.cost(batch)
        return batch
