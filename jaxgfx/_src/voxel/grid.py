"""Device-side reads of an encoded volume, shared by the ray caster's passes.

The pointer map (4.4.6, Fig. 4.11) is read per map cell: :func:`_map_column` finds a
cell's column (through the instance tile map), :func:`_column_runs` reads a
column's RLE elements as voxel height ranges (through the running sums of
:attr:`~jaxgfx.raycast.RLEVolume.tail_sums`, no decode of the elements above),
:func:`_column_elements` all of them.  :func:`_dda_entry` starts the exact
3-D DDA (Amanatides & Woo) of the per-pixel re-walk (:mod:`.warp`); the reference
renderer (:mod:`.reference`) has its own, so that it checks this one.
:func:`_safe_div` is the one guarded division of the chapter.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxgfx._src.voxel.codec import MAX_DRAW, unpack_element

__all__: list[str] = []  # private helpers of the chapter's modules


def _safe_div(a, b, eps=1e-12):
    # Double-where: the untaken branch never sees b == 0.
    small = jnp.abs(b) < eps
    sign = jnp.where(b < 0, -1.0, 1.0)
    return a / jnp.where(small, sign * eps, b)


# ---------------------------------------------------------------------------
# Pointer map and RLE columns (4.4.6)
# ---------------------------------------------------------------------------


def _tail_slots(rle) -> int:
    """Static count of the tail elements the columns reach, a shared tail once per column."""
    return rle.elements.shape[0] if rle.column_tails is None else rle.column_tails


def _level_tables(rle):
    """``(levels, pointer-map offset, X, Y, Z)`` of every mip level, int32 arrays."""
    L = rle.levels
    off = jnp.asarray(np.asarray(rle.level_offsets, np.int32))
    sx = jnp.asarray(np.asarray([s[0] for s in rle.level_shapes], np.int32))
    sy = jnp.asarray(np.asarray([s[1] for s in rle.level_shapes], np.int32))
    sz = jnp.asarray(np.asarray([s[2] for s in rle.level_shapes], np.int32))
    return L, off, sx, sy, sz


def _cell_height(rle, c):
    """Vertical size, in level-0 voxels, of a cell whose horizontal size is ``c`` (= 2^l).

    ``c`` for the thesis's cube mips, 1 for column mips (:func:`~jaxgfx.raycast.encode_rle`'s
    ``mips="column"``, which keep every level's heights exact).
    """
    return jnp.ones_like(c) if rle.column_mips else c


def _map_column(rle, ix, iz, lev, off, sx, sz):
    """Map cell (ix, iz) at level ``lev``: (inside the map, tile holds an instance, entry).

    The map is a grid of object-sized tiles (:func:`~jaxgfx.raycast.place_instances`);
    the cell's column is the object's column at the position inside its tile.
    """
    tx, tz = rle.tiles.shape
    xl, zl = sx[lev], sz[lev]
    if (tx, tz) == (1, 1):
        # One tile: no integer division (out-of-map cells get some entry, unused).
        in_map = (ix >= 0) & (iz >= 0) & (ix < xl) & (iz < zl)
        return in_map, rle.tiles[0, 0] >= 0, off[lev] + ix * zl + iz
    ti = jnp.floor_divide(ix, xl)
    tk = jnp.floor_divide(iz, zl)
    in_map = (ix >= 0) & (iz >= 0) & (ti < tx) & (tk < tz)
    tile = rle.tiles[jnp.clip(ti, 0, tx - 1), jnp.clip(tk, 0, tz - 1)]
    col = off[lev] + (ix - ti * xl) * zl + (iz - tk * zl)
    return in_map, tile >= 0, col


def _column_head(rle, col, ok, level_height):
    """A column's first element (inline in the pointer map): ``(safe, n, draw0, bottom0)``.

    ``safe``: the entry to read (0 where ``ok`` is False), ``n``: its element
    count (0 there), ``draw0``: the first element's drawn voxels, ``bottom0``:
    the height of its bottom voxel.
    """
    safe = jnp.where(ok, col, 0)
    n = jnp.where(ok, rle.count[safe].astype(jnp.int32), 0)
    skip0, draw0 = unpack_element(rle.first[safe].astype(jnp.int32))
    return safe, n, draw0, level_height - skip0 - draw0


def _element_bottoms(rle, safe, bottom0, j):
    """Bottom voxel heights of a column's elements ``j`` (any shape, valid for ``j < n``)."""
    idx = jnp.clip(rle.ptr[safe].astype(jnp.int32) + j - 1, 0, rle.elements.shape[0] - 1)
    below = rle.tail_sums[0, idx].astype(jnp.int32)
    return jnp.where(j == 0, bottom0, bottom0 - below), idx


def _column_runs(rle, safe, n, draw0, bottom0, j):
    """Elements ``j`` of one column, read directly: ``(top, bottom, valid, drawn_before)``.

    From the running sums over the column's tail
    (:attr:`~jaxgfx.raycast.RLEVolume.tail_sums`), not a prefix sum over every
    element above: the traversal's step reads 4 elements of a column of up to
    ``max_elements``.
    """
    bottom, idx = _element_bottoms(rle, safe, bottom0, j)
    tail = j > 0
    draw = jnp.where(tail, rle.elements[idx].astype(jnp.int32) & MAX_DRAW, draw0)
    before = jnp.where(tail, draw0 + rle.tail_sums[1, idx].astype(jnp.int32), 0)
    return bottom + draw - 1, bottom, (j < n) & (draw > 0), before


def _column_elements(rle, col, ok, level_height, E):
    """Up to E elements of one column: ``(n, top, bottom, valid, drawn_before)``."""
    safe, n, draw0, bottom0 = _column_head(rle, col, ok, level_height)
    top, bottom, valid, drawn_before = _column_runs(rle, safe, n, draw0, bottom0, jnp.arange(E))
    return n, top, bottom, valid, drawn_before


# ---------------------------------------------------------------------------
# 3-D DDA set-up
# ---------------------------------------------------------------------------


def _dda_entry(shape, origin, direction, t_start):
    """Entry of a ray into the grid ``[0, shape)`` for an Amanatides-Woo 3-D DDA.

    Returns:
        ``(1/direction, t_enter, t_exit, first voxel index, step, axis-parallel mask)``.
    """
    dims = jnp.asarray(shape, jnp.float32)
    inv = _safe_div(1.0, direction, 1e-12)
    t0 = (0.0 - origin) * inv
    t1 = (dims - origin) * inv
    t_enter = jnp.maximum(jnp.max(jnp.minimum(t0, t1)), t_start)
    t_exit = jnp.min(jnp.maximum(t0, t1))
    p = origin + direction * t_enter
    dmax = jnp.asarray(shape, jnp.int32) - 1
    idx = jnp.clip(jnp.floor(p).astype(jnp.int32), 0, dmax)
    step = jnp.where(direction > 0, 1, -1).astype(jnp.int32)
    tiny = jnp.abs(direction) < 1e-12
    return inv, t_enter, t_exit, idx, step, tiny
