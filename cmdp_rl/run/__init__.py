"""Run plumbing: the run directory, resume, the progress line, sweeps and Hydra callbacks."""
