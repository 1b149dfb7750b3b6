"""The trust-region family: the natural-gradient step (``natural_gradient``), CPO, PCPO, TRPO-Lagrangian."""
