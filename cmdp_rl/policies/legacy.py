"""Checkpoints written before the agent model (the ``ActorCritic`` triple): their network keys,
renamed to the :class:`~cmdp_rl.policies.agent.Agent`'s.

The networks are the same modules under other names; only the parameter and buffer names moved
(``actor.module.0.module.net.0.weight`` -> ``actor.body.net.0.weight``, ``critic.`` ->
``critics.reward.``, ...). Optimizer states need no change: each optimizer's parameters are in the
same order as before.
"""

from __future__ import annotations

import re

from torch import nn

# Old prefix -> new prefix, per policy family; the first match wins.
_RULES = [
    # MLP: actor = ProbabilisticActor(TensorDictModule(GaussianHead(net))), critics TensorDictModule(net)
    (r"^actor\.module\.0\.module\.log_std$", "actor.head.log_std"),
    (r"^actor\.module\.0\.module\.(center|half_width)$", r"actor.head.\1"),
    (r"^actor\.module\.0\.module\.net\.", "actor.body.net."),
    (r"^(critic|cost_critic)\.module\.", r"\1:body.net."),
    # LSTM/GRU: TensorDictSequential(encoder, memory, head) in each network
    (r"^actor\.module\.0\.module\.0\.module\.", "actor.body.encoder."),
    (r"^actor\.module\.0\.module\.1\.", "actor.body.memory."),
    (r"^actor\.module\.0\.module\.2\.module\.log_std$", "actor.head.log_std"),
    (r"^actor\.module\.0\.module\.2\.module\.(center|half_width)$", r"actor.head.\1"),
    (r"^actor\.module\.0\.module\.2\.module\.net\.", "actor.body.head."),
    (r"^(critic|cost_critic)\.module\.0\.module\.", r"\1:body.encoder."),
    (r"^(critic|cost_critic)\.module\.1\.", r"\1:body.memory."),
    (r"^(critic|cost_critic)\.module\.2\.module\.", r"\1:body.head."),
]
# Transformer: TensorDictSequential(window, TensorDictModule(GaussianHead(trunk))) in the actor,
# TensorDictSequential(window, TensorDictModule(trunk)) in each critic.
_TRANSFORMER_RULES = [
    (r"^actor\.module\.0\.module\.1\.module\.log_std$", "actor.head.log_std"),
    (r"^actor\.module\.0\.module\.1\.module\.(center|half_width)$", r"actor.head.\1"),
    (r"^actor\.module\.0\.module\.1\.module\.net\.", "actor.body.trunk."),
    (r"^(critic|cost_critic)\.module\.1\.module\.", r"\1:body.trunk."),
]
_SIGNAL = {"critic": "critics.reward.", "cost_critic": "critics.cost."}


def is_legacy(networks: dict) -> bool:
    return any(k.startswith(("critic.", "cost_critic.")) for k in networks)


def convert_networks(networks: dict, agent: nn.Module) -> dict:
    """An old ``ActorCritic`` state dict as ``agent``'s. Keys it cannot place raise ``KeyError``."""
    wanted = set(agent.state_dict())
    out = {}
    for key, value in networks.items():
        if key.startswith("normalizers."):
            out[key] = value
            continue
        new = None
        for pattern, repl in (*_TRANSFORMER_RULES, *_RULES):
            if re.match(pattern, key):
                candidate = re.sub(pattern, repl, key)
                if ":" in candidate:
                    net, rest = candidate.split(":", 1)
                    candidate = _SIGNAL[net] + rest.removeprefix("body.").join(["body.", ""]) if False else \
                        _SIGNAL[net] + rest
                if candidate in wanted:
                    new = candidate
                    break
        if new is None:
            # An observation normalizer inside a network is the shared one: saved under normalizers.
            if re.search(r"(^|\.)(obs_norm|0)\.stats\.", key) or ".obs_norm." in key:
                continue
            raise KeyError(f"old checkpoint key {key!r} has no place in the agent")
        out[new] = value
    return out


def upgrade_algo_state(state: dict, agent: nn.Module) -> dict:
    """An algorithm's checkpoint state with its networks in the agent's names (unchanged if new)."""
    if "networks" not in state or not is_legacy(state["networks"]):
        return state
    return {**state, "networks": convert_networks(state["networks"], agent)}


__all__ = ["convert_networks", "is_legacy", "upgrade_algo_state"]
