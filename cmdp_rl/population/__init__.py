"""Population training: P independent agents trained by one process as one batched tensor program
(``python train.py ... population.seeds=S population.grid.<field>=[...]``, docs/population.md):
``spec`` (what a population is, each agent's config), ``params`` and ``fused`` (the stacked
networks, their Adam and fused pass), ``env`` (the agents' envs as one), ``agent`` (acting and
valuing), ``update`` (the stacked backend of the shared update), ``trainer`` (the run).
"""

from cmdp_rl.population.spec import PER_AGENT_FIELDS, PopulationConfig, agent_configs, population_active

__all__ = ["PER_AGENT_FIELDS", "PopulationConfig", "agent_configs", "population_active", "train_population"]


def __getattr__(name: str):  # the trainer imports the whole toolkit: load it on first use
    if name == "train_population":
        from cmdp_rl.population.trainer import train_population

        return train_population
    raise AttributeError(name)
