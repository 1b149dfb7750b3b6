"""Off-policy algorithms: SAC and TD3 with their Lagrangian variants, and what they share (``common``)."""
