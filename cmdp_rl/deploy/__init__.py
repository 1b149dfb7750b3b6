"""The deployed policy: what a run hands back at its end (the last iterate, an average of iterates, or a
mixture of snapshots chosen on their measured values)."""
