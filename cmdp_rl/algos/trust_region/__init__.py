"""The trust-region family: the natural-gradient step (conjugate gradient, line search), CPO, PCPO and
TRPO-Lagrangian."""
