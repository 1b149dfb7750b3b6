"""The rollout and what is computed from it before an update: the batch's keys, action spaces, the
collector, the advantages of reward and cost, and observation normalisation."""
