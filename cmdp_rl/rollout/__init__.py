"""The rollout: the batch's keys, action spaces, the collector, reward and cost GAE, normalisation."""
