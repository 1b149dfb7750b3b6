"""Safety-Gymnasium's Point and Car navigation tasks, batched: the world, its layouts, the pseudo-lidar and one module per task family."""
