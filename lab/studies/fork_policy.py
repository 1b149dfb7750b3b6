"""A trained policy on the fork (env=fork), valued exactly: each actor's action probabilities in
every state, read off the network, then one linear solve (:func:`cmdp_rl.envs.grid.tabular.evaluate`).
A mixture of actors drawn once per episode has the mean of its members' values: values are linear
in the occupancy measure (``deploy.policy=mixture`` deploys such a mixture: cmdp_rl/deploy/mixture.py;
``deploy.policy=average`` a parameter average instead, one actor: cmdp_rl/deploy/average.py). No episodes, so no
sampling noise: a learning test can hold a policy to the budget itself."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from cmdp_rl.deploy.mixture import MixtureBody
from cmdp_rl.envs.fork.model import ForkCMDP
from cmdp_rl.envs.grid.optimum import ConstrainedOptimum
from cmdp_rl.envs.grid.tabular import evaluate
from cmdp_rl.policies.agent import Actor
from cmdp_rl.rollout import keys
from lab.studies.grid_policy import Gap


@torch.no_grad()
def action_table(actor: Actor, model: ForkCMDP) -> np.ndarray:
    """``pi[s, a]`` of a memoryless actor: its action probabilities on each state's one-hot observation."""
    obs = torch.eye(model.obs_dim)[: model.num_states]
    return (
        actor.dist({keys.OBS: obs, keys.IS_INIT: torch.ones(model.num_states, 1, dtype=torch.bool)})
        .probs.double()
        .numpy()
    )


def mixture_gap(
    actors: Sequence[Actor], model: ForkCMDP, best: ConstrainedOptimum, weights: Sequence[float] | None = None
) -> Gap:
    """The exact return and costs of the policy that draws one of ``actors`` per episode (uniformly,
    or with ``weights``) and follows it (one actor: that actor's own policy), against the optimum ``best``."""
    each = evaluate(model, np.stack([action_table(a, model) for a in actors]))
    w = np.full(len(actors), 1.0 / len(actors)) if weights is None else np.asarray(weights, dtype=float)
    return Gap(
        float(w @ each.ret),
        tuple(float(c) for c in w @ each.costs),
        float(best.ret),
        tuple(float(d) for d in best.budgets),
    )


def members_of(actor: Actor) -> list[Actor]:
    """The member actors of a mixture; any other actor is its own one member."""
    return list(actor.body.members) if isinstance(actor.body, MixtureBody) else [actor]


def weights_of(actor: Actor) -> list[float]:
    """The probability of drawing each of :func:`members_of`'s actors."""
    members = members_of(actor)
    weights = actor.body.weights if isinstance(actor.body, MixtureBody) else None
    return [1.0 / len(members)] * len(members) if weights is None else weights.tolist()


__all__ = ["action_table", "members_of", "mixture_gap", "weights_of"]
