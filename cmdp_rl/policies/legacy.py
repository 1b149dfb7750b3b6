"""Checkpoints written before the agent model (the ``ActorCritic`` triple, up to commit 6e31f3c):
their network entries under the :class:`~cmdp_rl.policies.agent.Agent`'s names.

The networks are the same modules, built in the same order, under other names: the old actor was a
``ProbabilisticActor`` around TensorDict modules (``actor.module.0.module.net.0.weight``), the
critics were ``critic.`` and ``cost_critic.`` (now ``critics.reward.`` and ``critics.cost.``), and
the observation normalizer sat inside each network (``...net.0.stats.mean``) as well as under
``normalizers.``. So, network by network, the old entries other than the normalizer's statistics
are the new ones in the same order; each pair must agree in shape and in its last name
(``weight``, ``log_std``, ``weight_ih_l0``, ...), else the checkpoint is refused. The normalizer's
statistics come from ``normalizers.``, the one copy every network shares. One exception to the
order: the old MLP actor's input encoder, which now comes first (see :func:`convert_networks`).

Optimizer states need no change: each optimizer's parameters are in the same order as before.
Used wherever a checkpoint is loaded: ``rundir.load_trained`` (evaluate.py) and a resume
(``trainer.train``); ``tests/test_old_runs.py`` checks it on runs written by the old code.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

# Old network prefix -> the agent's.
NETWORKS = {"actor.": "actor.", "critic.": "critics.reward.", "cost_critic.": "critics.cost."}
NORMALIZERS = "normalizers."


def is_legacy(networks: dict) -> bool:
    """Whether a checkpoint's network state is the old ``ActorCritic``'s."""
    return any(k.startswith(("critic.", "cost_critic.")) for k in networks)


def _is_statistic(key: str) -> bool:
    """A running statistic of an observation normalizer (``...stats.mean``), which every network
    shares with ``normalizers.obs``."""
    return ".stats." in key or key.startswith("stats.")


def convert_networks(networks: dict[str, torch.Tensor], agent: nn.Module) -> dict[str, torch.Tensor]:
    """An old ``ActorCritic`` state dict as ``agent``'s state dict. Raises ``KeyError`` naming the
    first entry that does not fit."""
    target = agent.state_dict(keep_vars=True)
    out: dict[str, torch.Tensor] = {k: v for k, v in networks.items() if k.startswith(NORMALIZERS)}
    # Every alias of a normalizer's statistics in the agent is the same tensor as under normalizers.
    shared = {v.data_ptr(): k for k, v in target.items() if k.startswith(NORMALIZERS)}
    for key, value in target.items():
        if key.startswith(NORMALIZERS):
            continue
        if value.data_ptr() in shared:
            source = shared[value.data_ptr()]
            if source not in out:
                raise KeyError(f"old checkpoint lacks {source!r} (the statistics of {key!r})")
            out[key] = out[source]
    for old_prefix, new_prefix in NETWORKS.items():
        old = [k for k in networks if k.startswith(old_prefix) and not _is_statistic(k)]
        # The old MLP actor kept its input encoder (previous action and cost) inside the Gaussian
        # head's network (``...module.net.encoder.``); the agent keeps it in the body, which comes
        # first.
        old.sort(key=lambda k: 0 if ".module.net.encoder." in k else 1)
        new = [k for k in target if k.startswith(new_prefix) and k not in out]
        if len(old) != len(new):
            raise KeyError(
                f"old checkpoint has {len(old)} entries under {old_prefix!r}, the agent {len(new)} under {new_prefix!r}"
            )
        for o, n in zip(old, new):
            if o.rsplit(".", 1)[-1] != n.rsplit(".", 1)[-1] or networks[o].shape != target[n].shape:
                raise KeyError(
                    f"old checkpoint entry {o!r} {tuple(networks[o].shape)} does not fit {n!r} {tuple(target[n].shape)}"
                )
            out[n] = networks[o]
    missing = target.keys() - out.keys()
    if missing:
        raise KeyError(f"old checkpoint has nothing for {sorted(missing)[:3]}")
    return out


def upgrade_algo_state(state: dict[str, Any], agent: nn.Module) -> dict[str, Any]:
    """An algorithm's checkpoint state with its networks in the agent's names (unchanged if new)."""
    if "networks" not in state or not is_legacy(state["networks"]):
        return state
    return {**state, "networks": convert_networks(state["networks"], agent)}


__all__ = ["convert_networks", "is_legacy", "upgrade_algo_state"]
