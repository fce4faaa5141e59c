"""Procedural voxel trees (thesis 4.3.3)."""

from __future__ import annotations

import jax
import numpy as np

from jaxgfx._src.checks import check_int
from jaxgfx._src.voxel.voxset import Voxels, _check_resolution, dense_to_voxels

__all__ = ["procedural_tree"]


def procedural_tree(resolution: int = 64, *, key, depth: int = 4) -> Voxels:
    """A voxel tree: spheres along branches, midpoint displacement, 2-3-way splits (4.3.3).

    Args:
        resolution: grid size (the tree fits a ``resolution``-cube).
        key: ``jax.random`` key; the same key gives the same tree.
        depth: branching generations.

    Returns:
        Surface :class:`Voxels` (trunk brown, leaf clusters green).
    """
    resolution = _check_resolution(resolution)
    if resolution < 8:
        raise ValueError(f"resolution must be >= 8 for a tree, got {resolution}")
    depth = check_int("depth", depth, low=1, high=7)
    rnd = iter(np.asarray(jax.random.uniform(key, (1 << 16,)), np.float64))
    R = float(resolution)
    spheres = []  # (center, radius, is_leaf)

    def branch_points(a, b, disp, level):
        # Random midpoint displacement: recursively insert displaced midpoints.
        if level == 0:
            return [a, b]
        m = 0.5 * (a + b) + disp * (np.array([next(rnd), next(rnd), next(rnd)]) - 0.5)
        return branch_points(a, m, disp * 0.5, level - 1)[:-1] + branch_points(
            m, b, disp * 0.5, level - 1
        )

    def grow(p0, direction, length, radius, gen):
        p1 = p0 + direction * length
        pts = branch_points(p0, p1, 0.35 * length, 3)
        for i in range(len(pts) - 1):
            a, b = pts[i], pts[i + 1]
            n = max(2, int(np.ceil(np.linalg.norm(b - a) / max(0.5 * radius, 0.5))))
            for t in np.linspace(0.0, 1.0, n, endpoint=False):
                spheres.append((a + t * (b - a), radius, False))
        if gen >= depth:
            spheres.append((p1, max(2.0, 2.5 * radius + 0.04 * R), True))
            return
        k = 2 + int(next(rnd) < 0.5)
        for j in range(k):
            ang = 2 * np.pi * (j + next(rnd) * 0.5) / k
            tilt = 0.5 + 0.4 * next(rnd)
            d = np.array([np.cos(ang) * tilt, 1.0, np.sin(ang) * tilt])
            d = 0.6 * direction + 0.4 * d / np.linalg.norm(d)
            d /= np.linalg.norm(d)
            grow(p1, d, length * (0.6 + 0.15 * next(rnd)), radius * 0.65, gen + 1)

    root = np.array([R / 2, 0.0, R / 2])
    grow(root, np.array([0.0, 1.0, 0.0]), 0.3 * R, 0.05 * R, 1)
    occ = np.zeros((resolution,) * 3, bool)
    col = np.zeros((resolution,) * 3 + (3,), np.uint8)
    g = np.arange(resolution) + 0.5
    for center, radius, leaf in spheres:
        lo = np.maximum(np.floor(center - radius).astype(int), 0)
        hi = np.minimum(np.ceil(center + radius).astype(int) + 1, resolution)
        if np.any(hi <= lo):
            continue
        xx, yy, zz = np.meshgrid(
            g[lo[0] : hi[0]], g[lo[1] : hi[1]], g[lo[2] : hi[2]], indexing="ij"
        )
        inside = (xx - center[0]) ** 2 + (yy - center[1]) ** 2 + (zz - center[2]) ** 2 <= radius**2
        sub = occ[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        csub = col[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        new = inside & ~sub
        shade = np.clip(yy / R, 0, 1)[..., None]
        if leaf:
            c = np.array([40, 120, 30]) + shade * np.array([60, 90, 30])
        else:
            c = np.array([80, 50, 25]) + shade * np.array([40, 30, 15])
        csub[new] = np.round(np.broadcast_to(c, new.shape + (3,))[new]).astype(np.uint8)
        sub |= inside
    return dense_to_voxels(occ, col)
