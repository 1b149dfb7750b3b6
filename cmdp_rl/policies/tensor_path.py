"""TensorDict modules run on plain tensors, where their structure allows it.

Why: for the small networks of this toolkit, tensordict's module dispatch, the probabilistic
module's bookkeeping and TensorDict construction cost several times the networks' own arithmetic
(at 8 envs, about 10 times an MLP actor's forward pass; see ``experiments/benchmark_throughput.py``).
The hot loops (the collector's steps, the PPO minibatches) call the wrapped ``nn.Module`` directly
and build the distribution exactly as ``ProbabilisticTensorDictModule`` does, so the numbers are
the same (``tests/test_collector.py`` and ``tests/test_algos.py`` check it). A module of any other
shape (a recurrent policy reading and writing state under ``"next"``) gets no such path in the
minibatch loop (it trains in recurrent mode on TensorDicts); for acting, :class:`StepProgram`
runs it on tensors too.
"""

from __future__ import annotations

from typing import Callable, Mapping

import torch
from tensordict.nn import (
    InteractionType,
    ProbabilisticTensorDictModule,
    ProbabilisticTensorDictSequential,
    TensorDictModule,
    TensorDictModuleBase,
    TensorDictSequential,
)
from tensordict.nn.probabilistic import interaction_type
from torch import distributions as D
from torch import nn
from torchrl.modules import GRUModule, LSTMModule

Entries = Mapping[str, torch.Tensor]  # root key -> tensor with a leading batch dim


def _plain(module: TensorDictModuleBase) -> bool:
    """A ``TensorDictModule`` around an ``nn.Module``, every key a root string."""
    return type(module) is TensorDictModule and all(isinstance(k, str) for k in (*module.in_keys, *module.out_keys))


def _sampler_ok(head_out_keys: list, prob: TensorDictModuleBase) -> bool:
    """A probabilistic module :class:`_Sampler` reproduces: one sample, root string keys, no
    spec projection, parameters written by the head."""
    return (
        isinstance(prob, ProbabilisticTensorDictModule)
        and all(isinstance(k, str) for k in (*prob.in_keys, *prob.out_keys))
        and not set(prob.in_keys) - set(head_out_keys)
        and prob.num_samples is None
        and len(prob.dist_sample_keys) == 1
        and not getattr(prob, "safe", False)  # torchrl's spec projection of samples
    )


class _Sampler:
    """The distribution and sampling step of a ``ProbabilisticTensorDictModule``, on tensors."""

    def __init__(self, prob: ProbabilisticTensorDictModule) -> None:
        self.dist_class = prob.distribution_class
        self.dist_kwargs = dict(prob.distribution_kwargs)
        self.dist_params = list(zip(prob.dist_keys, prob.in_keys))
        self.action_key = prob.out_keys[0]
        self.log_prob_key = prob.log_prob_key if prob.return_log_prob else None

    def dist(self, params: Entries) -> D.Distribution:
        return self.dist_class(**{dk: params[k] for dk, k in self.dist_params}, **self.dist_kwargs)

    def sample_into(self, out: dict) -> None:
        """Write the action (sampled under ``ExplorationType.RANDOM``, the deterministic sample
        under DETERMINISTIC) and its log-prob into ``out``, which holds the parameters."""
        dist = self.dist(out)
        mode = interaction_type()
        # As ProbabilisticTensorDictModule._dist_sample: RANDOM -> rsample if it exists, else sample.
        if mode is InteractionType.RANDOM:
            action = dist.rsample() if dist.has_rsample else dist.sample()
        elif mode is InteractionType.DETERMINISTIC:
            action = dist.deterministic_sample
        else:
            raise NotImplementedError(f"tensor path: exploration type {mode} (use RANDOM or DETERMINISTIC)")
        out[self.action_key] = action
        if self.log_prob_key is not None:
            out[self.log_prob_key] = dist.log_prob(action)


class TensorActor:
    """A stateless probabilistic actor (a head ``TensorDictModule`` feeding one distribution), on
    tensors. :meth:`dist` gives the distribution, :meth:`__call__` the entries the actor writes."""

    def __init__(self, head: TensorDictModule, prob: ProbabilisticTensorDictModule) -> None:
        self.net = head.module
        self.in_keys = list(head.in_keys)
        self.param_keys = list(head.out_keys)
        self.sampler = _Sampler(prob)

    @classmethod
    def wrap(cls, actor: TensorDictModuleBase) -> TensorActor | None:
        """A :class:`TensorActor` computing what ``actor`` computes, or None if its shape is other."""
        if not isinstance(actor, ProbabilisticTensorDictSequential) or len(actor.module) != 2:
            return None
        head, prob = actor.module
        if not _plain(head) or not _sampler_ok(list(head.out_keys), prob):
            return None
        return cls(head, prob)

    def params(self, inputs: Entries) -> dict[str, torch.Tensor]:
        out = self.net(*(inputs[k] for k in self.in_keys))
        return dict(zip(self.param_keys, out if isinstance(out, tuple) else (out,)))

    def dist(self, inputs: Entries) -> D.Distribution:
        return self.sampler.dist(self.params(inputs))

    def __call__(self, inputs: Entries) -> dict[str, torch.Tensor]:
        """The actor's outputs: distribution parameters, the action and its log-prob."""
        out = self.params(inputs)
        self.sampler.sample_into(out)
        return out


Step = Callable[[dict], None]  # updates a dict of entries (keys: strings or tuples) in place


def _compile(module: TensorDictModuleBase) -> Step | None:
    """``module``'s step-mode computation as a function on a dict of entries, or None if it holds
    a module of another kind. Handles plain ``TensorDictModule``s (any keys), torchrl's
    ``LSTMModule``/``GRUModule`` in step mode, ``TensorDictSequential`` (honouring
    ``selected_out_keys``) and probabilistic actors."""
    if type(module) is TensorDictModule:
        net, ins, outs = module.module, list(module.in_keys), list(module.out_keys)

        def plain(d: dict) -> None:
            out = net(*(d[k] for k in ins))
            d.update(zip(outs, out if isinstance(out, tuple) else (out,)))

        return plain
    if type(module) in (LSTMModule, GRUModule):
        return _compile_rnn(module)
    if isinstance(module, ProbabilisticTensorDictSequential) and len(module.module) == 2:
        head, prob = module.module
        head_step = _compile(head)
        if head_step is None or not _sampler_ok(list(head.out_keys), prob):
            return None
        sampler = _Sampler(prob)

        def actor(d: dict) -> None:
            head_step(d)
            sampler.sample_into(d)

        return actor
    if type(module) is TensorDictSequential:
        steps = [_compile(m) for m in module.module]
        if any(s is None for s in steps):
            return None
        outs = set(module.out_keys)  # the selected ones, if selected_out_keys was given

        def sequence(d: dict) -> None:
            before = set(d)
            for s in steps:
                s(d)
            for k in set(d) - before - outs:  # intermediates stay inside, as TensorDictSequential keeps them
                del d[k]

        return sequence
    return None


def _compile_rnn(module: LSTMModule | GRUModule) -> Step | None:
    """torchrl's recurrent module in step mode (``LSTMModule.forward`` with
    ``recurrent_mode=False``): the state read is zeroed where ``is_init``, one step of the
    ``nn.LSTM``/``nn.GRU``, state layout ``[batch, layers, hidden]``."""
    rnn = module.lstm if isinstance(module, LSTMModule) else module.gru
    if type(rnn) not in (nn.LSTM, nn.GRU) or rnn.bidirectional or getattr(rnn, "proj_size", 0) or not rnn.batch_first:
        return None
    ins, outs = list(module.in_keys), list(module.out_keys)
    x_key, state_keys, init_key = ins[0], ins[1:-1], ins[-1]
    y_key, next_keys = outs[0], outs[1:]

    def step(d: dict) -> None:
        if module.recurrent_mode:
            raise RuntimeError("tensor path: a recurrent module is stepped only in step mode")
        fresh = d[init_key].view(-1, 1, 1)
        states = [torch.where(fresh, torch.zeros_like(d[k]), d[k]).transpose(0, 1).contiguous() for k in state_keys]
        y, new = rnn(d[x_key].unsqueeze(1), tuple(states) if len(states) == 2 else states[0])
        d[y_key] = y.squeeze(1)
        for k, h in zip(next_keys, new if isinstance(new, tuple) else (new,)):
            d[k] = h.transpose(0, 1)

    return step


class StepProgram:
    """A policy of any structure :func:`_compile` knows (recurrent memory, a transformer window,
    critics stepped beside the actor), compiled to tensor steps for acting: the collector's tensor
    path for stateful policies. Same numbers as the TensorDict call (``tests/test_memory_policies.py``)."""

    def __init__(self, step: Step) -> None:
        self.step = step

    @classmethod
    def wrap(cls, policy: TensorDictModuleBase) -> StepProgram | None:
        step = _compile(policy)
        return None if step is None else cls(step)

    def __call__(self, inputs: Entries) -> dict:
        """Every entry after the step: the inputs and what the policy wrote."""
        d = dict(inputs)
        self.step(d)
        return d


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
