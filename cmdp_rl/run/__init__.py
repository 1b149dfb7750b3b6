"""One run: opening it (``start``), the training loop (``loop``) and what it trains (``kernel``), the end (``finish``),
its entry (``trainer``), checkpoints, resume, the run directory, the progress line and Hydra callbacks."""
