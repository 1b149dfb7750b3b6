"""P agents in one process (docs/population.md): ``spec``, the grid's configs; ``stacked``, their networks as one
tensor program; ``envs``, their envs as one; ``learner``, what their update steps; ``kernel``, what the run's training
loop trains; ``training`` and ``resume``, a population's run and its continuation."""

from cmdp_rl.population.spec import PER_AGENT_FIELDS, Population, PopulationConfig, agent_configs, population

__all__ = ["PER_AGENT_FIELDS", "Population", "PopulationConfig", "agent_configs", "population"]
