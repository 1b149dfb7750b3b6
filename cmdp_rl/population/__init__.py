"""P agents as one batched tensor program, for ``trainer.train`` (docs/population.md): ``spec`` (the
grid -> each agent's config, what the batched program covers), and the stacked kernel: ``params``
and ``fused`` (the stacked networks, their Adam and fused pass), ``env`` (the agents' envs as one),
``agent`` (acting and valuing), ``update`` (the stacked backend of the shared update).
"""

from cmdp_rl.population.spec import PER_AGENT_FIELDS, Population, PopulationConfig, agent_configs, population

__all__ = ["PER_AGENT_FIELDS", "Population", "PopulationConfig", "agent_configs", "population"]
