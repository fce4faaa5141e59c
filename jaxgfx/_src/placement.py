"""Standing objects on a terrain: column scans of a terrain function and placement records.

Used by the demo scene (:mod:`jaxgfx.showcase`) and its tests.  Everything works on any
terrain function f: Z^3 -> {0, 1} (thesis 3.3), not only height maps.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Placement", "column_top", "GroundPatch", "ground_patch"]


@dataclasses.dataclass(frozen=True)
class Placement:
    """Where one object stands: its lowest voxels or vertices in world units.

    Attributes:
        name: what the object is.
        kind: ``'voxel'`` or ``'mesh'``.
        bottom: (K, 3) world positions of the object's lowest layer: the bottom-face centres
            of its lowest voxels, or its lowest vertices.
        unit: world size of one of the object's voxels (1 for meshes).
    """

    name: str
    kind: str
    bottom: np.ndarray
    unit: float


def column_top(fn, xz: jax.Array, y_range: tuple[int, int]) -> jax.Array:
    """Top of the solid in integer voxel columns: the lowest air voxel above the highest solid one.

    Pure; callers jit it with ``y_range`` static (it sets the scan's shape).

    Args:
        fn: a terrain function f: Z^3 -> {0, 1} (thesis 3.3).
        xz: (K, 2) int32 column positions.
        y_range: ``(lo, hi)`` the scanned heights; the terrain's surface must lie inside.

    Returns:
        (K,) int32: y of the first voxel above the highest solid voxel (``lo`` if none).
    """
    lo, hi = (int(v) for v in y_range)
    ys = jnp.arange(lo, hi, dtype=jnp.int32)

    def one(c):
        pts = jnp.stack([jnp.full_like(ys, c[0]), ys, jnp.full_like(ys, c[1])], -1)
        solid = jax.vmap(fn)(pts)
        return jnp.max(jnp.where(solid, ys + 1, lo))

    return jax.vmap(one)(jnp.asarray(xz, jnp.int32))


class GroundPatch(NamedTuple):
    """Column tops of the terrain over a rectangle of columns (host lookups while placing).

    Attributes:
        x0, z0: world x, z of the first column.
        tops: (NX, NZ) int, :func:`column_top` of every column in the rectangle.
    """

    x0: int
    z0: int
    tops: np.ndarray

    def at(self, x, z) -> np.ndarray:
        """Surface height under world points ``(x, z)`` (the column each lies in).

        Raises:
            ValueError: a point outside the patch.
        """
        i = np.floor(np.asarray(x)).astype(np.int64) - self.x0
        k = np.floor(np.asarray(z)).astype(np.int64) - self.z0
        nx, nz = self.tops.shape
        if np.any((i < 0) | (i >= nx) | (k < 0) | (k >= nz)):
            raise ValueError("a point lies outside the ground patch")
        return self.tops[i, k]


def ground_patch(fn, centre_xz, radius: int, y_range) -> GroundPatch:
    """:class:`GroundPatch` of the ``(2 radius)^2`` columns around ``centre_xz`` (one scan)."""
    x0 = int(np.floor(centre_xz[0])) - radius
    z0 = int(np.floor(centre_xz[1])) - radius
    i, k = np.meshgrid(np.arange(2 * radius), np.arange(2 * radius), indexing="ij")
    xz = np.stack([i.ravel() + x0, k.ravel() + z0], -1).astype(np.int32)
    scan = jax.jit(column_top, static_argnums=2)
    tops = np.asarray(scan(fn, jnp.asarray(xz), tuple(int(v) for v in y_range)))
    return GroundPatch(x0, z0, tops.reshape(2 * radius, 2 * radius))
