"""Safety-Gymnasium's pseudo-lidar, batched: ``env=safe_nav``'s observation of each object group.

Each object lights the bin of its egocentric angle (16 bins around the robot) with
``max(0, range - d) / range`` (d its xy distance), and its two neighbours in proportion to where in
the bin it lies; the closest object wins. The range is 3 (the Circle tasks: 6).
"""

from __future__ import annotations

import numpy as np

LIDAR_BINS, LIDAR_MAX = 16, 3.0


def pseudo_lidar(
    objects_xy: np.ndarray, agent_pos: np.ndarray, agent_mat: np.ndarray, max_dist: float = LIDAR_MAX
) -> np.ndarray:
    """Safety-Gymnasium's pseudo-lidar of M objects per env: ``objects_xy`` ``[N, M, 2]``,
    the robot's position ``[N, 3]`` and frame ``[N, 3, 3]`` -> ``[N, 16]``."""
    n, m = objects_xy.shape[:2]
    out = np.zeros((n, LIDAR_BINS))
    if m == 0:
        return out
    world = np.concatenate([objects_xy, np.zeros((n, m, 1))], axis=-1) - agent_pos[:, None, :]
    ego = np.matmul(world, agent_mat)  # the offset in the robot's frame (row vector times frame)
    dist = np.hypot(ego[..., 0], ego[..., 1])
    angle = np.arctan2(ego[..., 1], ego[..., 0]) % (2 * np.pi)
    width = 2 * np.pi / LIDAR_BINS
    bins = (angle / width).astype(np.int64) % LIDAR_BINS
    reading = np.maximum(0.0, max_dist - dist) / max_dist
    alias = (angle - width * bins) / width  # where in its bin: it lights the neighbours in proportion
    rows = np.broadcast_to(np.arange(n)[:, None], bins.shape)
    np.maximum.at(out, (rows, bins), reading)
    np.maximum.at(out, (rows, (bins + 1) % LIDAR_BINS), alias * reading)
    np.maximum.at(out, (rows, (bins - 1) % LIDAR_BINS), (1 - alias) * reading)
    return out


__all__ = ["LIDAR_BINS", "LIDAR_MAX", "pseudo_lidar"]
