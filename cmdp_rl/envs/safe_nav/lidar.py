"""Safety-Gymnasium's 16-bin pseudo-lidar, batched over envs and object groups. Each object's 16 bins are
built whole and the maximum taken over objects: the reference's bin-by-bin maximum, to the last bits
the kernels picked for each shape move (tests/test_safe_nav.py), with no scatter (which numpy and torch
spell differently)."""

from __future__ import annotations

import math

import numpy as np

from cmdp_rl.envs.safe_nav.arrays import Array, like, namespace, zeros

LIDAR_BINS, LIDAR_MAX = 16, 3.0


def pseudo_lidar(objects_xy: Array, agent_pos: Array, agent_mat: Array, max_dist: float = LIDAR_MAX) -> Array:
    """Safety-Gymnasium's pseudo-lidar of M objects per env: ``objects_xy`` ``[N, M, 2]``,
    the robot's position ``[N, 3]`` and frame ``[N, 3, 3]`` -> ``[N, 16]``."""
    return pseudo_lidars([objects_xy], agent_pos, agent_mat, max_dist)[0]


def pseudo_lidars(groups: list[Array], agent_pos: Array, agent_mat: Array, max_dist: float = LIDAR_MAX) -> list[Array]:
    """:func:`pseudo_lidar` of each group of objects (``[N, M_g, 2]`` each), in one pass over all the groups'
    objects: an object's arithmetic is the same whatever it is batched with, though the kernels that run it may
    round the last bits otherwise for another shape (tests/test_safe_nav_speed.py: within 1e-12)."""
    xp = namespace(agent_pos)
    n, sizes = agent_pos.shape[0], [g.shape[1] for g in groups]
    if sum(sizes):
        lit = _lit(xp.concatenate(groups, axis=1) if len(groups) > 1 else groups[0], agent_pos, agent_mat, max_dist)
    out, lo = [], 0
    for m in sizes:
        reading = zeros(agent_pos, (n, LIDAR_BINS))
        if m:
            reading = xp.maximum(reading, xp.amax(lit[:, lo : lo + m], axis=1))
        out.append(reading)
        lo += m
    return out


def _lit(objects_xy: Array, agent_pos: Array, agent_mat: Array, max_dist: float) -> Array:
    """What each object lights ``[N, M, 16]``: its bin and, aliased, the two neighbours."""
    xp = namespace(agent_pos)
    n, m = objects_xy.shape[:2]
    flat = zeros(agent_pos, (n, m, 1))
    world = xp.concatenate([objects_xy, flat], axis=-1) - agent_pos[:, None, :]
    ego = xp.matmul(world, agent_mat)  # the offset in the robot's frame (row vector times frame)
    dist = xp.hypot(ego[..., 0], ego[..., 1])
    angle = xp.arctan2(ego[..., 1], ego[..., 0]) % (2 * math.pi)
    width = 2 * math.pi / LIDAR_BINS
    bins = xp.floor(angle / width) % LIDAR_BINS  # whole numbers (as floats), angle >= 0
    reading = xp.clip(max_dist - dist, 0.0, None) / max_dist
    alias = (angle - width * bins) / width  # where in its bin: it lights the neighbours in proportion
    k = like(np.arange(LIDAR_BINS), angle)
    at = (bins[..., None] == k, (bins[..., None] + 1) % LIDAR_BINS == k, (bins[..., None] - 1) % LIDAR_BINS == k)
    lit = xp.where(at[0], reading[..., None], 0.0)
    lit = xp.maximum(lit, xp.where(at[1], (alias * reading)[..., None], 0.0))
    return xp.maximum(lit, xp.where(at[2], ((1 - alias) * reading)[..., None], 0.0))
