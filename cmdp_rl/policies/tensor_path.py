"""TensorDict modules run on plain tensors, where their structure allows it.

Why: for the small networks of this toolkit, tensordict's module dispatch, the probabilistic
module's bookkeeping and TensorDict construction cost several times the networks' own arithmetic
(at 8 envs, about 10 times an MLP actor's forward pass; see ``experiments/benchmark_throughput.py``).
The hot loops (the collector's steps, the PPO minibatches) call the wrapped ``nn.Module`` directly
and build the distribution exactly as ``ProbabilisticTensorDictModule`` does, so the numbers are
the same (``tests/test_collector.py`` and ``tests/test_algos.py`` check it). A module of any other
shape (a recurrent policy reading and writing state under ``"next"``) gets no tensor path: the
caller keeps the TensorDict call.
"""

from __future__ import annotations

from typing import Mapping

import torch
from tensordict.nn import (
    InteractionType,
    ProbabilisticTensorDictModule,
    ProbabilisticTensorDictSequential,
    TensorDictModule,
    TensorDictModuleBase,
)
from tensordict.nn.probabilistic import interaction_type
from torch import distributions as D

Entries = Mapping[str, torch.Tensor]  # root key -> tensor with a leading batch dim


def _plain(module: TensorDictModuleBase) -> bool:
    """A ``TensorDictModule`` around an ``nn.Module``, every key a root string."""
    return type(module) is TensorDictModule and all(isinstance(k, str) for k in (*module.in_keys, *module.out_keys))


class TensorActor:
    """A stateless probabilistic actor (a head ``TensorDictModule`` feeding one distribution), on
    tensors. :meth:`dist` gives the distribution, :meth:`__call__` the entries the actor writes."""

    def __init__(self, head: TensorDictModule, prob: ProbabilisticTensorDictModule) -> None:
        self.net = head.module
        self.in_keys = list(head.in_keys)
        self.param_keys = list(head.out_keys)
        self.dist_class = prob.distribution_class
        self.dist_kwargs = dict(prob.distribution_kwargs)
        self.dist_params = list(zip(prob.dist_keys, prob.in_keys))
        self.action_key = prob.out_keys[0]
        self.log_prob_key = prob.log_prob_key if prob.return_log_prob else None

    @classmethod
    def wrap(cls, actor: TensorDictModuleBase) -> TensorActor | None:
        """A :class:`TensorActor` computing what ``actor`` computes, or None if its shape is other."""
        if not isinstance(actor, ProbabilisticTensorDictSequential) or len(actor.module) != 2:
            return None
        head, prob = actor.module
        if (
            not _plain(head)
            or not isinstance(prob, ProbabilisticTensorDictModule)
            or not all(isinstance(k, str) for k in (*prob.in_keys, *prob.out_keys))
            or set(prob.in_keys) - set(head.out_keys)
            or prob.num_samples is not None
            or len(prob.dist_sample_keys) != 1
            or getattr(prob, "safe", False)  # torchrl's spec projection of samples
        ):
            return None
        return cls(head, prob)

    def params(self, inputs: Entries) -> dict[str, torch.Tensor]:
        out = self.net(*(inputs[k] for k in self.in_keys))
        return dict(zip(self.param_keys, out if isinstance(out, tuple) else (out,)))

    def dist(self, inputs: Entries) -> D.Distribution:
        return self._dist(self.params(inputs))

    def _dist(self, params: Entries) -> D.Distribution:
        return self.dist_class(**{dk: params[k] for dk, k in self.dist_params}, **self.dist_kwargs)

    def __call__(self, inputs: Entries) -> dict[str, torch.Tensor]:
        """The actor's outputs: distribution parameters, the action (sampled under
        ``ExplorationType.RANDOM``, the deterministic sample under DETERMINISTIC) and its log-prob."""
        out = self.params(inputs)
        dist = self._dist(out)
        mode = interaction_type()
        # As ProbabilisticTensorDictModule._dist_sample: RANDOM -> rsample if it exists, else sample.
        if mode is InteractionType.RANDOM:
            action = dist.rsample() if dist.has_rsample else dist.sample()
        elif mode is InteractionType.DETERMINISTIC:
            action = dist.deterministic_sample
        else:
            raise NotImplementedError(f"TensorActor: exploration type {mode} (use RANDOM or DETERMINISTIC)")
        out[self.action_key] = action
        if self.log_prob_key is not None:
            out[self.log_prob_key] = dist.log_prob(action)
        return out


class TensorModule:
    """A plain ``TensorDictModule`` (such as a critic) on tensors: entries in, its first output out."""

    def __init__(self, module: TensorDictModule) -> None:
        self.net = module.module
        self.in_keys = list(module.in_keys)

    @classmethod
    def wrap(cls, module: TensorDictModuleBase) -> TensorModule | None:
        return cls(module) if _plain(module) and len(module.out_keys) == 1 else None

    def __call__(self, inputs: Entries) -> torch.Tensor:
        return self.net(*(inputs[k] for k in self.in_keys))
