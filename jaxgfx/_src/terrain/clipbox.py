"""Clip-Boxes: sampling, nesting and the differential update (thesis 3.4.1-3.4.3, 3.4.5-3.4.6).

A Clip-Box (3.4.1-3.4.2) of level ``l`` holds ``N^3`` voxels of edge ``2^l`` whose
origin is snapped to the ``2^(l+1)`` lattice, so each box's boundary lies on the
lattice of the next outer box and boxes nest concentrically about the viewer (3.4.5).
Moving a box reuses the overlap and samples only the newly exposed slabs (3.4.6,
Fig. 3.11).
"""

from __future__ import annotations

import dataclasses
from typing import cast

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_int, static_field
from jaxgfx._src.terrain.functions import _I32
from jaxgfx._src.terrain.sampling import sample_terrain

__all__ = [
    "ClipBox",
    "clipbox_origin",
    "sample_clipbox",
    "NestedClipBoxes",
    "nested_origins",
    "is_nested",
    "slab_thickness",
    "shift_clipbox",
    "reused_fraction",
    "MAX_LEVEL",
    "max_levels",
    "check_levels",
]


# --------------------------------------------------------------------------------------
# The Clip-Box and its place in the world (3.4.1-3.4.2)
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ClipBox:
    """One Clip-Box level (3.4.1-3.4.2).

    Attributes:
        origin: (3,) int32 world coordinate of voxel (0, 0, 0); a multiple of 2^(level+1).
        voxels: (N, N, N) bool, indexed [x, y, z]; voxel i samples ``origin + i 2^level``.
        level: () int32, voxel edge is ``2^level`` (a leaf, so one compilation of
            the meshing steps serves every level).
        size: static int, N.
    """

    origin: jax.Array
    voxels: jax.Array
    level: jax.Array
    size: int = static_field()


def _check_size(size) -> int:
    size = check_int("size", size)
    if size < 8 or size % 8:
        raise ValueError(
            f"size (N) must be a multiple of 8 and >= 8 (even so boxes nest on the outer "
            f"lattice, /8 for the nesting margin), got {size}"
        )
    return size


MAX_LEVEL = 20
"""The coarsest Clip-Box level: voxels of edge ``2^20``."""


def _check_level(level) -> int:
    return check_int("level", level, low=0, high=MAX_LEVEL)


def max_levels(size: int) -> int:
    """The most nested levels ``L`` that boxes of ``size`` (N) voxels per edge can have.

    Levels run from 0 to ``MAX_LEVEL`` (20), and the boxes' world coordinates are int32:
    the viewer's neighbourhood of ``2 N 2^L`` voxels (where the outer box, ``N 2^(L-1)``
    wide, can move to) must fit in ``[-(2^31 - 1), 2^31 - 1]``; N = 64 allows 21 levels,
    N = 1024 allows 19.

    Raises:
        TypeError: ``size`` is not an int.
        ValueError: ``size`` is not a multiple of 8 >= 8.
    """
    size = _check_size(size)
    levels = MAX_LEVEL + 1
    while levels > 1 and _reach(size, levels) > 2**31 - 1:
        levels -= 1
    return levels


def _reach(size: int, levels: int) -> int:
    """Voxels around the viewer that ``levels`` boxes of ``size`` need in int32: ``2 N 2^L``."""
    return 2 * size * (1 << levels)


def check_levels(levels, size: int) -> int:
    """``levels`` as an int in ``[1, max_levels(size)]``; raises naming ``levels`` otherwise."""
    levels = check_int("levels", levels, low=1)
    most = max_levels(size)
    if levels > most:
        raise ValueError(
            f"levels must be <= {most} for boxes of size {size} (levels run 0..{MAX_LEVEL} and "
            f"the outer box must fit int32 world coordinates), got {levels}"
        )
    return levels


def clipbox_origin(viewer, level: int, size: int) -> np.ndarray:
    """Origin of the level-``level`` box centred on ``viewer``, snapped to the 2^(level+1) grid.

    Args:
        viewer: (3,) integer world coordinate (host values).
    Returns:
        (3,) int64 origin.
    """
    level, size = _check_level(level), _check_size(size)
    v = np.asarray(viewer)
    if v.shape != (3,) or not np.issubdtype(v.dtype, np.integer):
        raise ValueError(f"viewer must be 3 integers, got {viewer!r}")
    step = 2 << level
    return np.floor_divide(v.astype(np.int64) - (size // 2) * (1 << level), step) * step


# --------------------------------------------------------------------------------------
# Procedural volume-data creation (3.4.3)
# --------------------------------------------------------------------------------------


def sample_clipbox(terrain, origin: jax.Array, level: jax.Array, *, size: int) -> ClipBox:
    """Samples a full Clip-Box of ``size^3`` voxels (3.4.3).

    Args:
        terrain: terrain pytree.
        origin: (3,) int32, a multiple of 2^(level+1) (see :func:`clipbox_origin`).
        level: the level: a Python int (static under ``jit``; lets the binned CSG
            share bins between voxels, see :meth:`CSGTerrain.sample_grid`) or a
            () int32 (may be traced).
        size: static N.
    """
    vox = sample_terrain(terrain, origin, level=level, shape=(size, size, size))
    level = jnp.asarray(level, _I32)
    return ClipBox(origin=jnp.asarray(origin, _I32), voxels=vox, level=level, size=size)


# --------------------------------------------------------------------------------------
# Nesting (3.4.5, Fig. 3.2, Fig. 3.10)
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class NestedClipBoxes:
    """State of ``L`` nested Clip-Boxes, level 0 innermost (3.4.5, Fig. 3.2).

    Attributes:
        boxes: L :class:`ClipBox` (volume data, cached for differential updates).
        meshes: L welded, smoothed :class:`ClipBoxMesh` ready to draw.
    """

    boxes: tuple
    meshes: tuple

    @property
    def levels(self) -> int:
        return len(self.boxes)

    def origins(self) -> np.ndarray:
        """(L, 3) int64 box origins (host)."""
        return np.stack([np.asarray(b.origin, np.int64) for b in self.boxes])


def nested_origins(viewer, *, levels: int, size: int) -> np.ndarray:
    """(L, 3) origins of boxes centred on ``viewer`` (host side, Fig. 3.10)."""
    levels = check_levels(levels, size)
    return np.stack([clipbox_origin(viewer, lvl, size) for lvl in range(levels)])


def is_nested(inner_origin, outer_origin, level: int, size: int) -> bool:
    """Inner box inside the outer one with a margin of one outer voxel (3.4.5, host side).

    The invariant :meth:`ClipBoxPipeline.plan` keeps between consecutive levels.

    Args:
        inner_origin: (3,) integer origin of the level-``level`` box.
        outer_origin: (3,) integer origin of the level-``level + 1`` box.
        level: the inner box's level.
        size: N of both boxes.
    """
    s_out = 2 << level
    lo = np.asarray(inner_origin) - np.asarray(outer_origin)
    hi = lo + size * (1 << level)
    return bool(np.all(lo >= s_out) and np.all(hi <= size * s_out - s_out))


# --------------------------------------------------------------------------------------
# Moving the view-point: the differential update (3.4.6, Fig. 3.11)
# --------------------------------------------------------------------------------------


def slab_thickness(delta) -> tuple[int, int, int]:
    """Static slab thickness per axis for a box shift of ``delta`` voxels (host side).

    The next power of two >= ``|delta_d|`` (0 when the axis does not move), so only a
    handful of shapes are ever compiled.
    """
    out = []
    for d in np.abs(np.asarray(delta, np.int64)):
        out.append(0 if d == 0 else 1 << int(np.ceil(np.log2(d))))
    return cast(tuple[int, int, int], tuple(out))  # one entry per axis of a (3,) delta


def shift_clipbox(
    terrain,
    box: ClipBox,
    new_origin: jax.Array,
    *,
    slabs: tuple[int, int, int],
    level: int | None = None,
):
    """Differential update (3.4.6, Fig. 3.11): reuse the overlap, sample only new slabs.

    Args:
        terrain: terrain pytree.
        box: the current box.
        new_origin: (3,) int32, a multiple of 2^(level+1).
        slabs: static per-axis slab thickness >= ``|shift|`` in voxels (see
            :func:`slab_thickness`); only ``sum_d slabs_d N^2`` points are sampled.
        level: optional static copy of ``box.level`` for the sampling fast paths
            (see :func:`sample_clipbox`); it must equal ``box.level``.
    Returns:
        The moved :class:`ClipBox`; equals :func:`sample_clipbox` at ``new_origin``.
    """
    n, lvl = box.size, box.level
    new_origin = jnp.asarray(new_origin, _I32)
    delta = jnp.right_shift(new_origin - box.origin, lvl)  # voxels
    vox = jnp.roll(box.voxels, -delta, axis=(0, 1, 2))
    for axis, t in enumerate(slabs):
        if t == 0:
            continue
        # The slab is t >= |delta| voxels thick: it covers the exposed voxels and
        # re-samples a few reused ones, which the terrain gives back unchanged, so
        # it is written over the box as a whole (in place, no mask over N^3).
        start = jnp.where(delta[axis] > 0, n - t, 0)
        s_origin = new_origin.at[axis].add(start << lvl)
        shape = [n, n, n]
        shape[axis] = t
        slab = sample_terrain(
            terrain,
            s_origin,
            level=lvl if level is None else level,
            shape=(shape[0], shape[1], shape[2]),
        )
        vox = jax.lax.dynamic_update_slice(
            vox, slab, tuple(jnp.where(a == axis, start, 0) for a in range(3))
        )
    return ClipBox(origin=new_origin, voxels=vox, level=lvl, size=n)


def reused_fraction(old_origin, new_origin, level: int, size: int) -> float:
    """Fraction of the moved box's voxels copied from the old box (3.4.6), host side."""
    d = np.abs(np.asarray(new_origin, np.int64) - np.asarray(old_origin, np.int64)) >> level
    return float(np.prod(np.clip(size - d, 0, size)) / float(size) ** 3)
