"""Off-policy algorithms: what SAC and TD3 (and their Lagrangian variants) share (``common``), the replay
buffer and the target networks."""
