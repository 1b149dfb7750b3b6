"""A trained policy on a suite instance (``cmdp_rl.envs.suite``), valued exactly for the suite's study
(``lab/studies/cmdp_suite.py``): the actor's action probabilities at every (t, s), read off the network
on the env's own observations, then backward induction (``cmdp_rl.envs.suite.model.evaluate``). No
episodes, so no sampling noise: a run's deployed policy can be held to its budget itself.

``deterministic``: the policy evaluation runs with ``eval_deterministic=true`` (the most likely
action, ``policies/distributions.py``), as a one-hot table. A mixture of actors drawn once per
episode (``deploy.policy=mixture``) has the weighted mean of its members' values, values being
linear in the occupancy measure (Altman 1999, ch. 3). Only a memoryless policy (``policy=mlp``
without ``include_prev_action``/``include_prev_cost``) is a table; any other is refused.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import torch

from cmdp_rl.envs.suite.model import FiniteCMDP, Values, evaluate
from cmdp_rl.policies.agent import Actor
from cmdp_rl.rollout import keys


@torch.no_grad()
def action_table(actor: Actor, cmdp: FiniteCMDP, deterministic: bool = False) -> np.ndarray:
    """``pi[t, s, a]`` of a memoryless actor: its action probabilities (``deterministic``: its most
    likely action, one-hot) on the observation of each (t, s), t < H."""
    extra = set(actor.body.in_keys) - {keys.OBS, keys.IS_INIT}
    if actor.body.recurrent or extra:
        raise ValueError(
            f"action_table: the policy reads {sorted(map(str, extra))} or carries a state; only a memoryless "
            "policy is a table"
        )
    H, S = cmdp.horizon, cmdp.num_states
    steps, states = torch.meshgrid(torch.arange(H), torch.arange(S), indexing="ij")
    obs = observations(cmdp, states.reshape(-1), steps.reshape(-1))
    probs = actor.dist({keys.OBS: obs, keys.IS_INIT: torch.ones(H * S, 1, dtype=torch.bool)}).probs.double()
    if deterministic:  # the mode, ties to the first action as torch's argmax breaks them
        probs = torch.nn.functional.one_hot(probs.argmax(-1), cmdp.num_actions).double()
    return probs.reshape(H, S, cmdp.num_actions).numpy()


def observations(cmdp: FiniteCMDP, states: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
    """The env's observations ``[N, S + H + 1]`` of states ``[N]`` at time steps ``[N]`` (``envs/suite/env.py``)."""
    eye_s = torch.eye(cmdp.num_states, device=states.device)
    eye_t = torch.eye(cmdp.horizon + 1, device=states.device)
    return torch.cat([eye_s[states], eye_t[steps]], dim=-1)


def mixture_values(
    actors: Sequence[Actor], cmdp: FiniteCMDP, weights: Sequence[float] | None = None, deterministic: bool = False
) -> Values:
    """Exact ``J`` and ``J_c`` of the policy that draws one of ``actors`` per episode (uniformly, or
    with ``weights``) and follows it; one actor: that actor's own values."""
    each = evaluate(cmdp, np.stack([action_table(a, cmdp, deterministic) for a in actors]))
    w = np.full(len(actors), 1.0 / len(actors)) if weights is None else np.asarray(weights, dtype=float)
    return Values(ret=np.asarray(w @ each.ret), costs=w @ each.costs)


def deployed_values(agent: Any, cmdp: FiniteCMDP, deterministic: bool = False) -> Values:
    """Exact values of what a run deploys: its actor, or the mixture ``deploy.policy=mixture`` built."""
    from lab.studies.fork_policy import members_of, weights_of

    return mixture_values(members_of(agent.actor), cmdp, weights_of(agent.actor), deterministic)


__all__ = ["action_table", "deployed_values", "mixture_values"]
