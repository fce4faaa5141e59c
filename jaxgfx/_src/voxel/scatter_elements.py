"""The scatter's elements (step 3 of :mod:`.scatter`): what a frame pairs with its planes.

A single-object map's elements are its flat list, column heads then tails, each
with its cell's runs of sorted planes (:func:`_flat_elements`).  An instance map
(:func:`~jaxgfx.raycast.place_instances`) stores the object's columns once and
stands a column in every tile that holds the object, so its elements are
enumerated per tile and mip level instead (:func:`_tile_levels`): a tile at
level ``l`` contributes the object's level-``l`` elements where some plane
crossing the tile spends part of its level-``l`` stretch over it, so a frame
enumerates the instances in view in their LOD bands, never the map.  The
element instances, near tiles first, are gathered a chunk at a time
(:func:`_instance_chunk`: each one's map cell and planes); the ray buffer keeps
``tile * N + element``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera
from jaxgfx._src.compaction import running_max, running_sum
from jaxgfx._src.voxel.grid import (
    _cell_height,
    _column_head,
    _column_runs,
    _level_tables,
    _tail_slots,
)
from jaxgfx._src.voxel.scatter_planes import (
    _box_corners,
    _box_planes,
    _column_cells,
    _column_planes,
    _near_first,
    _Planes,
)
from jaxgfx._src.voxel.scatter_warp import _H_BITS, _XZ_BITS, _Elements
from jaxgfx._src.voxel.walk import _once

__all__ = ["default_chunk"]

# Planes of a column's first run: the packed ``planes`` word ``n1 | lo1 << 16``, both
# below 2^16 (the word's top bit is lo1's: read it back with a logical shift).
_N_BITS = 16


def _pack_runs(n1, lo1):
    """The packed ``planes`` word of a first run of ``n1`` sorted planes from ``lo1``."""
    return n1 | (lo1 << _N_BITS)


def _unpack_runs(planes):
    """``(n1, lo1)`` of a packed ``planes`` word, ``lo1`` read unsigned (the top bit is its)."""
    return planes & ((1 << _N_BITS) - 1), jax.lax.shift_right_logical(planes, jnp.int32(_N_BITS))


def default_chunk(width: int, height: int) -> int:
    """Element instances an instance map's frame gathers at once: a power of two >= W H.

    At the one-pixel LOD a frame holds about one element instance per pixel in
    view (each cell about a pixel wide), so most frames take one chunk; a frame
    with more draws its chunks in turn into the same table (``stats["passes"]``
    does not count them; ``traversal_steps`` does).
    """
    return 1 << max(14, int(np.ceil(np.log2(max(width * height, 1)))))


def _slot_runs(first, nonempty, head, start, size: int):
    """(size,) int32: the run each of slots ``start .. start + size - 1`` lies in.

    Runs of slots lie back to back from ``first`` (ascending, (n,) int32), the
    ``nonempty`` ones (n,) holding slots; ``head`` is the run of slot ``start``.
    A running max of marks at the runs' first slots: one scatter and a scan,
    where a search per slot costs XLA:CPU more.
    """
    rel = first - start
    at = nonempty & (rel >= 0) & (rel < size)
    mark = (
        jnp.full((size,), -1, jnp.int32)
        .at[jnp.where(at, rel, size)]
        .max(jnp.arange(first.shape[0], dtype=jnp.int32), mode="drop")
        .at[0]
        .max(head)
    )
    return running_max(mark)


def _object_elements(rle, cam: Camera):
    """The object's elements, flat (step 3's input), cells in the object's own tile.

    Returns ``(elements, col)``: :class:`_Elements` whose ``n_pairs`` is 1 for an
    element and 0 for an empty slot and whose ``planes`` are not set; (N,) the
    pointer-map entry of each.
    """
    C = rle.count.shape[0]
    ix_c, iz_c, lev_c = (jnp.asarray(a) for a in _column_cells(rle))
    cnt = rle.count.astype(jnp.int32)
    NT = _tail_slots(rle)
    if rle.column_tails is None:
        # Each stored tail element in one column: the columns' tails are the
        # stored ones, in the pointers' order.
        start = rle.ptr.astype(jnp.int32)
    else:
        # Columns sharing a stored tail (share_columns): each column's tail is
        # enumerated for it, the columns' tails back to back.
        tails = jnp.maximum(cnt - 1, 0)
        start = running_sum(tails) - tails
    # Tail slot i lies in the run of the column whose first slot is the last at or before it.
    owner = jnp.clip(_slot_runs(start, cnt >= 2, 0, 0, NT), 0, C - 1)
    col = jnp.concatenate([jnp.arange(C, dtype=jnp.int32), owner])
    j = jnp.concatenate(
        [jnp.zeros((C,), jnp.int32), jnp.arange(NT, dtype=jnp.int32) - start[owner] + 1]
    )
    _, _, sy, _ = _level_tables(rle)[1:]
    lev = lev_c[col]
    safe, n, draw0, bottom0 = _column_head(rle, col, jnp.ones(col.shape, bool), sy[lev])
    top, bottom, valid, drawn_before = _column_runs(rle, safe, n, draw0, bottom0, j)
    valid = valid & (j >= 0) & (j < n)
    cy = _cell_height(rle, jnp.left_shift(1, lev).astype(jnp.float32))
    # Front to back in a column: down from the eye's height below it, up above
    # it (walk._unrank's order; the two groups never meet one ray).
    above = bottom.astype(jnp.float32) * cy > cam.position[1]
    rank = jnp.where(above, 2 * rle.max_elements - 1 - j, j)
    el = _Elements(
        n_pairs=valid.astype(jnp.int32),
        cell=_once(ix_c[col] | (iz_c[col] << _XZ_BITS) | (lev << (2 * _XZ_BITS))),
        heights=_once(bottom | (top << _H_BITS) | (rank << (2 * _H_BITS))),
        planes=jnp.zeros_like(col),
        color=_once(rle.color_ptr[safe].astype(jnp.int32) + drawn_before),
    )
    return el, col


def _flat_elements(rle, cam: Camera, pl: _Planes) -> _Elements:
    """A single-object map's elements with their cells and planes (step 3's input)."""
    el, col = _object_elements(rle, cam)
    lo1, n1, n2 = _column_planes(rle, cam, pl)
    return el._replace(
        n_pairs=_once(jnp.where(el.n_pairs > 0, n1[col] + n2[col], 0)),
        planes=_once(_pack_runs(n1[col], lo1[col])),
    )


class _TileLevels(NamedTuple):
    """An instance map's tiles at each mip level that some plane crosses, near ones first."""

    tile: jax.Array  # (TX TZ L,) int32 tile index ``tx * TZ + tz``
    lev: jax.Array  # (TX TZ L,) int32 its level
    first: jax.Array  # (TX TZ L,) int32 its first element instance (its elements in a row)
    incl: jax.Array  # (TX TZ L,) int32 one past its last
    order: jax.Array  # (N,) int32 the object's elements by level (empty slots last)
    start: jax.Array  # (L,) int32 each level's first in ``order``


def _tile_levels(rle, cam: Camera, pl: _Planes, obj: _Elements) -> _TileLevels:
    """The element instances a frame can draw, as runs of the object's levels (step 2).

    A tile at level ``l`` contributes the object's level-``l`` elements where
    some plane crosses the tile's square and spends part of its stretch at
    ``l`` there (:func:`~.scatter_planes._box_planes`), so a frame enumerates
    the instances in view in their LOD bands, not the map.
    """
    TX, TZ = rle.tiles.shape
    L = rle.levels
    X0, _, Z0 = rle.level_shapes[0]
    # Near tiles first (what _hidden culls depends on it, the frame does not),
    # each tile's levels in a row.
    ex, ez = cam.position[0], cam.position[2]
    tile = jnp.repeat(_near_first(TX, TZ, ex - 0.5 * TX * X0, ez - 0.5 * TZ * Z0), L)
    lev = jnp.tile(jnp.arange(L, dtype=jnp.int32), TX * TZ)
    x0 = ((tile // TZ) * X0).astype(jnp.float32) - ex
    z0 = ((tile % TZ) * Z0).astype(jnp.float32) - ez
    x1, z1 = x0 + X0, z0 + Z0
    corner = _box_corners(pl, x0, z0, x1, z1)
    _, n1, n2 = _box_planes(rle, pl, corner, x0, z0, x1, z1, lev)
    # The object's elements by level, by counting (XLA:CPU sorts slowly).
    lev_e = obj.cell >> (2 * _XZ_BITS)
    of_level = (lev_e[:, None] == jnp.arange(L)[None, :]) & (obj.n_pairs > 0)[:, None]
    rank = running_sum(of_level.astype(jnp.int32))
    per_level = rank[-1]
    start = jnp.cumsum(per_level) - per_level
    N = lev_e.shape[0]
    mine = jnp.take_along_axis(rank, lev_e[:, None], 1)[:, 0]
    at = jnp.where(obj.n_pairs > 0, start[lev_e] + mine - 1, N)
    by_level = jnp.zeros((N,), jnp.int32).at[at].set(jnp.arange(N, dtype=jnp.int32), mode="drop")
    has = jnp.asarray(rle.tiles).reshape(-1)[tile] >= 0
    count = jnp.where(has & (n1 + n2 > 0), per_level[lev], 0)
    incl = running_sum(count)
    return _TileLevels(
        tile=tile, lev=lev, first=incl - count, incl=incl, order=by_level, start=start
    )


def _instance_chunk(rle, cam: Camera, pl: _Planes, obj: _Elements, tl: _TileLevels, start, size):
    """Element instances ``start .. start + size - 1`` of :func:`_tile_levels`' runs.

    Returns ``(elements, ids)``: their :class:`_Elements` in map cells, with their
    planes (an instance past the frame's last has none), and (size,) each one's
    writer id ``tile * N + element`` (what the ray buffer keeps, read back by
    :func:`~.scatter_warp.warp_texels`).
    """
    TX, TZ = rle.tiles.shape
    N = obj.cell.shape[0]
    slot = start + jnp.arange(size, dtype=jnp.int32)
    head = jnp.searchsorted(tl.incl, start, side="right").astype(jnp.int32)
    runs = _slot_runs(tl.first, tl.incl > tl.first, head, start, size)
    i = jnp.clip(runs, 0, tl.first.shape[0] - 1)
    live = slot < tl.incl[-1]
    lev, tile = tl.lev[i], tl.tile[i]
    e = tl.order[jnp.clip(tl.start[lev] + slot - tl.first[i], 0, N - 1)]
    _, _, sx, _, sz = _level_tables(rle)
    mask = (1 << _XZ_BITS) - 1
    cell = obj.cell[e]
    ix = (tile // TZ) * sx[lev] + (cell & mask)
    iz = (tile % TZ) * sz[lev] + ((cell >> _XZ_BITS) & mask)
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    x0 = ix.astype(jnp.float32) * c - cam.position[0]
    z0 = iz.astype(jnp.float32) * c - cam.position[2]
    x1, z1 = x0 + c, z0 + c
    corner = _box_corners(pl, x0, z0, x1, z1)
    lo1, n1, n2 = _box_planes(rle, pl, corner, x0, z0, x1, z1, lev)
    el = _Elements(
        n_pairs=_once(jnp.where(live, n1 + n2, 0)),
        cell=_once(ix | (iz << _XZ_BITS) | (lev << (2 * _XZ_BITS))),
        heights=_once(obj.heights[e]),
        planes=_once(_pack_runs(n1, lo1)),
        color=obj.color[e],
    )
    return el, tile * N + e
