"""The rollout and what is computed from it before an update: the batch's keys, action spaces, the
collector, the advantages of reward and cost, observation normalisation, and the episode-cost
estimate J_c the multipliers read."""
