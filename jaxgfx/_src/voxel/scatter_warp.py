"""The scattered ray buffer read per pixel: the warp of 4.5.5 (Eq. 4.6) for :mod:`.scatter`.

:func:`~.scatter.scatter_ray_buffer` leaves the writer of each texel of its last
pass in a table of the planes' rows back to back, and every pixel's writers
from the earlier passes kept per pixel; here each pixel reads its own, the
nearest box its ray enters wins (:func:`~.warp._nearest_candidate`, the lists'
warp's choice).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxgfx._src.camera import Camera, pixel_rays
from jaxgfx._src.voxel.grid import _level_tables
from jaxgfx._src.voxel.planes import Segments
from jaxgfx._src.voxel.walk import _once
from jaxgfx._src.voxel.warp import _nearest_candidate, _ray_buffer_texel

__all__ = ["RayBuffer", "warp_texels"]

# Bit fields of the scatter's packed per-element words (checked by
# scatter.check_scatter_scene).
_XZ_BITS = 14  # map cell x and z; with 3 bits of level the cell word stays positive
_H_BITS = 12  # voxel heights


class _Elements(NamedTuple):
    """Every RLE element, flat: the column heads, then the tails; (N,) int32.

    An instance map's chunk (:func:`~.scatter_elements._instance_chunk`) holds element
    instances instead, cells in the map.
    """

    n_pairs: jax.Array  # planes that cross the element's cell (0: empty slot)
    cell: jax.Array  # ix | iz << 14 | level << 28
    heights: jax.Array  # bottom | top << 12 | front-to-back rank << 24
    planes: jax.Array  # n1 | lo1 << 16 (bits, lo1 < 2^16): its column's sorted planes
    color: jax.Array  # colour index of the top voxel


class RayBuffer(NamedTuple):
    """The scattered ray buffer (:func:`scatter_ray_buffer`): its last pass's texels and the rest.

    A pixel's writer in a plane of the last pass is read from ``element``; in a
    plane of an earlier pass, from ``candidates`` (kept per pixel, for its
    nearest plane and ``n`` on either side).
    """

    element: jax.Array  # (texels,) int32 writer of each texel of the last pass (-1: none)
    offset: jax.Array  # () int32 the last pass's first texel
    base: jax.Array  # (P,) int32 texel of row 0 of each plane (rows back to back)
    rows: jax.Array  # (P,) int32 ``lo | hi << 16``: each plane's rows
    candidates: jax.Array  # (2 n + 1, H, W) int32 writers from earlier passes (-1: none)


def _pixel_writer(cam: Camera, seg: Segments, buffer: RayBuffer, di):
    """Each pixel's writer in its nearest plane ``+ di``, read from ``buffer.element``.

    Returns ``(ok, first, e)``: whether the pixel maps into the ray buffer; the
    plane's first texel less ``buffer.offset`` (a plane of an earlier pass
    where negative); its writer of the pixel's row (-1: none).
    """
    T, P = buffer.element.shape[0], buffer.base.shape[0]
    st, i0, cnt, row, ok = _ray_buffer_texel(cam, seg)
    plane = jnp.clip(st + jnp.clip(i0 + di, 0, jnp.maximum(cnt - 1, 0)), 0, P - 1)
    base, lo_hi = buffer.base[plane] - buffer.offset, buffer.rows[plane]
    lo, hi = lo_hi & 0xFFFF, lo_hi >> 16
    inside = ok & (row >= lo) & (row < hi)
    e = jnp.take(buffer.element, jnp.clip(base + row, 0, T - 1))
    return ok, base + lo, jnp.where(inside, e, -1)


def _harvest(cam: Camera, seg: Segments, buffer: RayBuffer, span: int | None):
    """``buffer.candidates`` with the writers of the pass in ``buffer.element`` added.

    The pass's planes have their first texels in ``[offset, offset + span)``
    (``span=None``: the last pass, every plane from ``offset`` on).
    """
    n = buffer.candidates.shape[0] // 2
    d = jnp.arange(-n, n + 1, dtype=jnp.int32)[:, None, None]
    ok, first, e = _pixel_writer(cam, seg, buffer, d)
    mine = ok & (first >= 0)
    if span is not None:
        mine = mine & (first < span)
    return jnp.where(mine, e, buffer.candidates)


def warp_texels(rle, cam: Camera, seg: Segments, buffer: RayBuffer, el: _Elements):
    """Displays a scattered ray buffer (4.5.5, Eq. 4.6), as :func:`~.warp.warp_lists` does lists.

    Every pixel reads the writers of its row in its nearest plane and the
    ``n`` planes on either side (``buffer.candidates``: (2 n + 1, H, W)) and
    keeps the nearest box its own ray enters (the nearest texel's where it
    enters none).

    Returns:
        ``(color (H, W, 3), depth (H, W), entered (H, W) bool)``.
    """
    origins, dirs = pixel_rays(cam, normalize=False)
    n = buffer.candidates.shape[0] // 2
    mask = (1 << _XZ_BITS) - 1
    hmask = (1 << _H_BITS) - 1

    # Every pixel's writers, the last pass's added to the earlier passes'.
    writers = _once(_harvest(cam, seg, buffer, None))

    _, _, sx, _, sz = _level_tables(rle)
    TZ, N = rle.tiles.shape[1], el.cell.shape[0]
    instanced = tuple(rle.tiles.shape) != (1, 1)

    def lookup(di):
        # Selects, not a gather: XLA:CPU runs this warp far slower with one.
        e = jnp.int32(-1)
        for j in range(2 * n + 1):
            e = jnp.where(di == j - n, writers[j], e)
        hit = e >= 0
        e = jnp.where(hit, e, 0)
        if instanced:
            # An instance map's writer is ``tile * N + element``
            # (scatter_elements._instance_chunk): the object's element, in its tile.
            tile = e // N
            e = e - tile * N
        cell, heights = el.cell[e], el.heights[e]
        ix, iz, lev = cell & mask, (cell >> _XZ_BITS) & mask, cell >> (2 * _XZ_BITS)
        if instanced:
            ix = ix + (tile // TZ) * sx[lev]
            iz = iz + (tile % TZ) * sz[lev]
        box = ((heights >> _H_BITS) & hmask, heights & hmask, ix, iz, lev)
        return hit, e, box

    return _nearest_candidate(rle, lookup, lambda e: el.color[e], origins, dirs, neighbors=n)
