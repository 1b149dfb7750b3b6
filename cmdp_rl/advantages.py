"""Twin critics, twin GAEs: advantages and value targets for reward and for cost.

Both GAEs are torchrl's, reading values the critics wrote beforehand (``value_network=None``), so
one critic pass serves both the estimate and the logging. A truncated step (time limit) is not
terminal: GAE bootstraps from ``V(next observation)`` unless ``("next", "terminated")`` is set,
for the reward critic and the cost critic alike.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.objectives.value import GAE

from cmdp_rl import keys
from cmdp_rl.policies.tensor_path import TensorModule

# Rows per critic call. Larger calls were slower per row here: their activations leave the cache,
# and glibc hands blocks of several MB back to the OS on free and page-faults them in again.
CHUNK_ROWS = 8192


def _chunked(net: torch.nn.Module, x: torch.Tensor) -> torch.Tensor:
    if x.shape[0] <= CHUNK_ROWS:
        return net(x)
    return torch.cat([net(part) for part in x.split(CHUNK_ROWS)])


def write_values(batch: TensorDictBase, critic: TensorDictModuleBase) -> None:
    """Write ``critic``'s values of the observations and of the next observations of a
    collector batch ``[N, T]`` (at the root and under ``"next"``).

    A memoryless critic of the observation is evaluated once per distinct observation: in a
    collector batch a step's next observation is the following step's observation unless the
    episode ended there (then it is the final one, and the following step starts from a reset
    one), so ``V(next obs)`` is the following step's ``V(obs)`` except at episode ends and on the
    last step, where it is computed. This halves the critic work of GAE. Any other critic (a
    recurrent one) is called on the batch and on its ``"next"`` as usual.
    """
    fast = TensorModule.wrap(critic)
    if fast is None or fast.in_keys != [keys.OBS]:
        critic(batch)
        critic(batch.get(keys.NEXT))
        return
    key = critic.out_keys[0]
    obs = batch.get(keys.OBS)
    values = _chunked(fast.net, obs.flatten(0, 1)).unflatten(0, obs.shape[:2])
    fresh = batch.get((keys.NEXT, keys.DONE)).squeeze(-1).clone()
    fresh[:, -1] = True
    next_values = torch.empty_like(values)
    next_values[:, :-1] = values[:, 1:]
    next_values[fresh] = _chunked(fast.net, batch.get((keys.NEXT, keys.OBS))[fresh])
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
    def __call__(self, batch: TensorDictBase, critic: TensorDictModuleBase, cost_critic: TensorDictModuleBase) -> TensorDictBase:
        """Write values, advantages and value targets of both critics into ``batch`` ([N, T])."""
        for module in (critic, cost_critic):
            write_values(batch, module)
        self.reward(batch)
        self.cost(batch)
        return batch
