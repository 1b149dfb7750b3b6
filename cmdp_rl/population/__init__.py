"""Population training: P independent agents trained by one process as one batched tensor program
(``python train.py ... population.seeds=S population.grid.<field>=[...]``).

- ``spec``: the ``population`` options, the per-agent fields, each agent's validated ``RunConfig``
  and the refusals (what the batched program does not cover);
- ``params``: the agents' networks as stacked parameters with a leading agent dimension, and Adam
  on them;
- ``env``: all agents' envs as one batched env (the env's own population form, else each agent's
  own env in turn);
- ``agent``: acting and valuing for all agents at once (the collector's and GAE's side);
- ``update``: the stacked backend of the PPO family's one minibatch step (``algos/update_backend.py``),
  each agent's own algorithm object around it;
- ``trainer``: the agents built, driven through the runs' loop (``run/loop.py``) into one run
  directory per agent, the population's checkpoint, resume and summary.
"""

from cmdp_rl.population.spec import PER_AGENT_FIELDS, PopulationConfig, agent_configs, population_active

__all__ = ["PER_AGENT_FIELDS", "PopulationConfig", "agent_configs", "population_active", "train_population"]


def __getattr__(name: str):  # the trainer imports the whole toolkit: load it on first use
    if name == "train_population":
        from cmdp_rl.population.trainer import train_population

        return train_population
    raise AttributeError(name)
