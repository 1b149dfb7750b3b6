"""Policies and training batches built by hand: an agent that acts by a fixed rule, a mixture of actors that
differ, a batch whose advantages favour one direction."""

import copy

import torch

from cmdp_rl import keys, load_config, make_agent, make_env
from cmdp_rl.deploy.mixture import mixture_actor


class ForwardPolicy:
    """The collector's side of an agent (``act``, ``in_keys``, ``initial_state``) around a plain
    function of the observation: for tests that drive an env with a fixed rule, not a network."""

    in_keys = [keys.OBS]

    def __init__(self, fn):
        self.fn = fn

    def initial_state(self, num_envs, device="cpu"):
        return {}

    def act(self, d, deterministic=False):
        return {keys.ACTION: self.fn(d[keys.OBS])}


def fork_mixture(members: int = 4, num_envs: int = 8):
    """A uniform mixture of ``members`` actors on the fork that differ (each its own output bias): its env, the
    agent acting with it, and the actors."""
    cfg = load_config({"env": {"name": "fork", "num_envs": num_envs}})
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env)
    actors = []
    for i in range(members):  # members that differ: each its own output bias
        actor = copy.deepcopy(agent.actor)
        with torch.no_grad():
            for p in actor.parameters():
                p.add_(0.3 * i)
        actors.append(actor)
    agent.actor = mixture_actor(actors)
    return env, agent, actors


def hand_built_units(actor, n=512, seed=0):
    """Training units with actions sampled from the actor; moving right (action above the mean) is
    rewarded and costs."""
    torch.manual_seed(seed)
    units = {keys.OBS: torch.rand(n, 2)}
    with torch.no_grad():
        params = actor.params(units)
        dist = actor.head.dist(params)
        action = dist.sample()
        units.update(params, **{keys.ACTION: action, keys.LOG_PROB: dist.log_prob(action)})
    push = (units[keys.ACTION] - units[keys.LOC]) / units[keys.SCALE]
    units[keys.ADVANTAGE] = push + 0.3 * torch.randn(n, 1)
    units[keys.COST_ADVANTAGE] = 0.5 * push + 0.1 * torch.randn(n, 1)
    return units
