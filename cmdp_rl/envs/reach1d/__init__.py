"""Reach1D, the seed's task: the gymnasium env, its batched torch twin, their options and the exact optimum."""
