"""P agents in one process (docs/population.md): ``spec``, the grid's configs; ``kernel``, one tensor program."""

from cmdp_rl.population.spec import PER_AGENT_FIELDS, Population, PopulationConfig, agent_configs, population

__all__ = ["PER_AGENT_FIELDS", "Population", "PopulationConfig", "agent_configs", "population"]
