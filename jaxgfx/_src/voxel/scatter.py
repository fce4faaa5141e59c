"""The ray buffer drawn column by column: every element scattered into the planes that cross it.

The thesis's traversal (4.5.4) walks each plane's cells front to back and keeps,
for every ray-buffer texel, the first element that covers its row.  That writer
is fixed by the walk's order alone: the coverage map and the floating horizon
(4.5.4.3) only skip elements that could not be first anywhere.  So the same ray
buffer comes out of a different loop order, which needs no dependent steps:

1. Every plane is a vertical half-plane through the eye; in the map it is a
   half-line from the eye in its x-z direction.  The planes are sorted by that
   direction once per frame (:func:`_plane_tables`).
2. A map cell is crossed by exactly the planes whose direction lies between the
   directions of its corners seen from the eye: one contiguous run of the
   sorted planes, or two where the run wraps behind the eye
   (:func:`_column_planes`).  These are the cells each plane's 2-D DDA visits.
3. Each RLE element of each column (:func:`_flat_elements`) is paired with the
   planes that cross its cell.  Per pair, the plane's line enters and leaves the
   cell at closed-form distances (the DDA's own arithmetic), clipped to the
   stretch the walk spends at the element's mip level (4.5.4.1); the element's
   corners project to rows with Eq. 4.5 (:func:`_pair_rows`).
4. The walk order of a pair within its plane is a key: mip level, then the cell's
   DDA ordinal (``±ix ± iz``: every DDA step adds one), then the element's
   front-to-back rank in its column.  A scatter-min of the key over the pair's
   rows keeps each texel's first writer, as the rasterizer's z-buffer keeps
   the nearest face; the pairs whose key won a texel write their element there.

Steps 3-4 run over the pairs in windows of a fixed size (``window`` pairs, at
most ``max(4 window, rows)`` rows) into a table of each plane's on-screen rows
back to back, so memory is bounded and the frame takes one loop step per
window (1 to 15 over ``rle_bench``'s views), each as wide as the window.
Elements are the same as the per-plane walk's; the coverage culling's saving is lost (every
element in a crossed cell is projected), while the thousands of dependent
one-cell steps are gone.  Instance maps are not enumerated this way (a
column stands in every tile that holds the object): :func:`scatter_ray_buffer`
takes single-object maps.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, camera_basis, pixel_rays
from jaxgfx._src.voxel.grid import (
    _cell_height,
    _column_head,
    _column_runs,
    _level_tables,
)
from jaxgfx._src.voxel.planes import Segments
from jaxgfx._src.voxel.traverse import _plane_init
from jaxgfx._src.voxel.walk import _TINY, _cell_exit, _once, _PlaneConsts, _rows_of, _slopes
from jaxgfx._src.voxel.warp import _nearest_candidate, _ray_buffer_texel
from jaxgfx._src.voxel.wide import _once_f

__all__ = [
    "RayBuffer",
    "scatter_frame",
    "scatter_ray_buffer",
    "warp_texels",
    "check_scatter_scene",
    "default_window",
    "default_texels",
]

_BIG = np.float32(1e30)
_NO_KEY = np.int32(2**31 - 1)
# Bit fields of the packed per-element words (checked by check_scatter_scene).
_XZ_BITS = 13  # map cell x and z
_H_BITS = 12  # voxel heights
_N_BITS = 14  # planes of a column's first run
_MAX_TEXELS = 1 << 24  # texel indices are exact in float32 below this


def default_texels(width: int, height: int, num_planes: int, rows: int) -> int:
    """Texel table size: 10 per pixel, at most every plane's whole column and ``2^24``.

    Ten per pixel holds the planes' on-screen rows at the default plane spacing on
    every acceptance view of ``experiments.rle_quality --traversal scatter``
    (``stats["buffer_overflow"]`` is 0 there).  Texel indices pass through
    float32 tables (see :func:`_plane_tables`), exact below ``2^24``.
    """
    return int(min(num_planes * rows, 10 * width * height, _MAX_TEXELS))


def default_window(width: int, height: int) -> int:
    """Pairs per loop step: a quarter of a frame's pixels, at least 2^14 (a power of two)."""
    return 1 << max(14, int(np.ceil(np.log2(max(width * height // 4, 1)))))


def check_scatter_scene(rle, num_planes: int, texels: int) -> None:
    """Raises ``ValueError`` where :func:`scatter_ray_buffer`'s packed words cannot hold a scene."""
    if tuple(rle.tiles.shape) != (1, 1):
        raise ValueError(
            "traversal='scatter' draws single-object maps; an instance map "
            f"(tiles {tuple(rle.tiles.shape)}) needs traversal='narrow' or 'wide'"
        )
    X, Y, Z = rle.shape
    if max(X, Z) >= 1 << _XZ_BITS or Y >= 1 << _H_BITS or rle.levels > 8:
        raise ValueError(
            f"traversal='scatter' takes maps below {1 << _XZ_BITS} columns a side, "
            f"{1 << _H_BITS} voxels high and 8 levels, got {rle.shape}, {rle.levels} levels"
        )
    if 2 * rle.max_elements > 128:
        raise ValueError(
            f"traversal='scatter' takes columns of at most 64 elements, got {rle.max_elements}"
        )
    if texels > _MAX_TEXELS:
        raise ValueError(f"texels must be at most 2^24 = {_MAX_TEXELS}, got {texels}")
    if num_planes >= 1 << _N_BITS:
        raise ValueError(
            f"traversal='scatter' takes at most {(1 << _N_BITS) - 1} planes, got {num_planes}"
        )


class _Planes(NamedTuple):
    """Per-plane data in direction order (:func:`_plane_tables`); (P,) arrays unless noted."""

    angle: jax.Array  # direction about the reference, ascending; inf for planes without rows
    n_live: jax.Array  # () planes with rows
    ref: jax.Array  # (2,) reference x-z direction of the angles
    hx: jax.Array
    hz: jax.Array
    s_min: jax.Array
    s_max: jax.Array
    hf: jax.Array
    p_num: jax.Array
    q_num: jax.Array
    lo: jax.Array  # float32 first row of the plane
    hi: jax.Array  # float32 one past its last row
    base: jax.Array  # float32 texel index of the plane's row 0 (its rows are back to back)
    t_level: jax.Array  # (levels + 1, P) where the walk enters each mip level; last: t_far
    texels: jax.Array  # () int32, the frame's texels (sum of the planes' rows)
    plane_base: jax.Array  # (P,) int32 ``base`` in plane order
    plane_lo: jax.Array  # (P,) int32 ``lo`` in plane order
    plane_hi: jax.Array  # (P,) int32 ``hi`` in plane order (``lo`` for a plane without rows)


def _running_max(x):
    return jax.lax.associative_scan(jnp.maximum, x)


def _plane_tables(rle, cam: Camera, seg: Segments, planes, *, rows: int, lod) -> _Planes:
    """Each plane's constants (the one-cell walk's), sorted by x-z direction (step 1)."""
    consts, c0 = jax.vmap(lambda p: _plane_init(rle, cam, seg, p, rows=rows, n_words=1))(planes)
    L = rle.levels
    ex, ez = cam.position[0], cam.position[2]
    hx, hz = consts.hx, consts.hz
    # The walk switches to level l at the exit of the first level-(l-1) cell that
    # leaves past lod 2^(l-1), into the parent of the cell across that exit
    # (walk._next_cell): followed here cell by cell, in integers, as the walk
    # does, since the level's first cell starts on a cell boundary.
    t_lev = [c0.t]
    ix, iz = c0.ix, c0.iz  # the walk's first cell (clipped into the map)
    exit_cell = jax.vmap(_cell_exit, in_axes=(0, None, 0, 0, None))
    for lev in range(1, L):
        band = lod * float(2 ** (lev - 1))
        _, t0_out, go_x0 = exit_cell(consts, cam, ix, iz, lev - 1)
        # Not out of the level's first cell yet: the cell holding the band's end.
        c = float(2 ** (lev - 1))
        xl, _, zl = rle.level_shapes[lev - 1]
        t_b = jnp.minimum(band, consts.t_far)
        bx = jnp.clip(jnp.floor((ex + hx * t_b) / c), 0, xl - 1).astype(jnp.int32)
        bz = jnp.clip(jnp.floor((ez + hz * t_b) / c), 0, zl - 1).astype(jnp.int32)
        _, tb_out, go_xb = exit_cell(consts, cam, bx, bz, lev - 1)
        first = t0_out >= band
        t_out = jnp.where(first, t0_out, tb_out)
        go_x = jnp.where(first, go_x0, go_xb)
        cx, cz = jnp.where(first, ix, bx), jnp.where(first, iz, bz)
        ix = jnp.where(go_x, cx + jnp.where(hx > 0, 1, -1), cx) >> 1
        iz = jnp.where(go_x, cz, cz + jnp.where(hz > 0, 1, -1)) >> 1
        t_next = jnp.minimum(jnp.maximum(t_out, t_lev[-1]), consts.t_far)
        t_lev.append(jnp.where(band >= consts.t_far, consts.t_far, t_next))
    t_lev.append(consts.t_far)
    live = ~c0.done
    _, _, forward = camera_basis(cam)
    fn = jnp.hypot(forward[0], forward[2])
    flat = fn < 1e-6
    ref = jnp.stack(
        [
            jnp.where(flat, 0.0, forward[0] / jnp.where(flat, 1.0, fn)),
            jnp.where(flat, 1.0, forward[2] / jnp.where(flat, 1.0, fn)),
        ]
    )
    angle = jnp.where(
        live, jnp.arctan2(ref[0] * hz - ref[1] * hx, ref[0] * hx + ref[1] * hz), jnp.inf
    )
    order = jnp.argsort(angle)
    # The texels: each plane's rows [lo, hi) back to back, in plane order.
    n_rows = jnp.where(live, c0.hi - c0.lo, 0)
    base = jnp.cumsum(n_rows) - n_rows - c0.lo
    # Pinned (see walk._once): a per-pair gather would recompute its table's
    # whole set-up for every pair otherwise.
    fl = lambda a: _once_f(a.astype(jnp.float32)[order])  # noqa: E731
    return _Planes(
        angle=angle[order],
        n_live=jnp.sum(live.astype(jnp.int32)),
        ref=ref,
        hx=fl(hx),
        hz=fl(hz),
        s_min=fl(consts.s_min),
        s_max=fl(consts.s_max),
        hf=fl(consts.hf),
        p_num=fl(consts.p_num),
        q_num=fl(consts.q_num),
        lo=fl(jnp.where(live, c0.lo, 0)),
        hi=fl(jnp.where(live, c0.hi, 0)),
        base=fl(base),
        t_level=_once_f(jnp.stack(t_lev)[:, order]),
        texels=jnp.sum(n_rows),
        plane_base=base,
        plane_lo=c0.lo,
        plane_hi=c0.lo + n_rows,
    )


def _column_cells(rle):
    """Per pointer-map entry (C,): its map cell ``(ix, iz, level)``; static NumPy arrays."""
    C = rle.count.shape[0]
    offs = np.asarray(rle.level_offsets, np.int64)
    lev = (np.searchsorted(offs, np.arange(C), side="right") - 1).astype(np.int64)
    zl = np.asarray([s[2] for s in rle.level_shapes], np.int64)[lev]
    q = np.arange(C) - offs[lev]
    return (q // zl).astype(np.int32), (q % zl).astype(np.int32), lev.astype(np.int32)


def _column_planes(rle, cam: Camera, pl: _Planes):
    """Per pointer-map entry: the sorted planes that cross its cell (step 2).

    Returns ``(lo1, n1, n2)`` (C,) int32: planes ``lo1 .. lo1 + n1 - 1`` and, where the
    cell's directions wrap past the back of the eye, ``0 .. n2 - 1`` too.
    """
    ix, iz, lev = (jnp.asarray(a) for a in _column_cells(rle))
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    ex, ez = cam.position[0], cam.position[2]
    x0 = ix.astype(jnp.float32) * c - ex
    z0 = iz.astype(jnp.float32) * c - ez
    x1, z1 = x0 + c, z0 + c
    rx, rz = pl.ref[0], pl.ref[1]
    corner = jnp.stack(
        [jnp.arctan2(rx * dz - rz * dx, rx * dx + rz * dz) for dx in (x0, x1) for dz in (z0, z1)]
    )
    a0, a1 = jnp.min(corner, axis=0), jnp.max(corner, axis=0)
    # A cell seen under more than a half turn lies across the back direction:
    # its directions are [a1, pi] and [-pi, a0].
    wrap = (a1 - a0) > np.pi
    lo1 = jnp.searchsorted(pl.angle, jnp.where(wrap, a1, a0), side="left").astype(jnp.int32)
    hi1 = jnp.searchsorted(pl.angle, jnp.where(wrap, np.pi, a1), side="right").astype(jnp.int32)
    hi2 = jnp.where(wrap, jnp.searchsorted(pl.angle, a0, side="right").astype(jnp.int32), 0)
    # The eye's own cell: every plane starts in it.
    eye = (x0 <= 0) & (x1 >= 0) & (z0 <= 0) & (z1 >= 0)
    if rle.levels > 1:
        # A level's cells outside every plane's stretch at that level draw nothing.
        live = jnp.isfinite(pl.angle)
        t_lo = jnp.min(jnp.where(live[None, :], pl.t_level[:-1], jnp.inf), axis=1)[lev]
        t_hi = jnp.max(jnp.where(live[None, :], pl.t_level[1:], -jnp.inf), axis=1)[lev]
        near = jnp.hypot(
            jnp.maximum(jnp.maximum(x0, -x1), 0.0), jnp.maximum(jnp.maximum(z0, -z1), 0.0)
        )
        far = jnp.hypot(
            jnp.maximum(jnp.abs(x0), jnp.abs(x1)), jnp.maximum(jnp.abs(z0), jnp.abs(z1))
        )
        eye = eye & (t_lo <= 0.0)
        reach = (far >= t_lo) & (near <= t_hi)
    else:
        reach = jnp.ones_like(eye)
    lo1 = jnp.where(eye, 0, lo1)
    hi1 = jnp.where(eye, pl.n_live, jnp.minimum(hi1, pl.n_live))
    n2 = jnp.where(eye, 0, jnp.minimum(hi2, pl.n_live))
    return lo1, jnp.where(reach, jnp.maximum(hi1 - lo1, 0), 0), jnp.where(reach, n2, 0)


class _Elements(NamedTuple):
    """Every RLE element, flat: the column heads, then the tails; (N,) int32."""

    n_pairs: jax.Array  # planes that cross the element's cell (0: empty slot)
    cell: jax.Array  # ix | iz << 13 | level << 26
    heights: jax.Array  # bottom | top << 12 | front-to-back rank << 24
    planes: jax.Array  # n1 | lo1 << 14: its column's sorted planes
    color: jax.Array  # colour index of the top voxel


def _flat_elements(rle, cam: Camera, pl: _Planes) -> _Elements:
    """The scene's elements with their cells and planes (step 3's input)."""
    C = rle.count.shape[0]
    NT = rle.elements.shape[0]
    ix_c, iz_c, lev_c = (jnp.asarray(a) for a in _column_cells(rle))
    cnt = rle.count.astype(jnp.int32)
    ptr = rle.ptr.astype(jnp.int32)
    # Tail element i belongs to the column whose pointer is the last at or before it.
    mark = (
        jnp.full((NT,), -1, jnp.int32)
        .at[jnp.where(cnt >= 2, ptr, NT)]
        .max(jnp.arange(C, dtype=jnp.int32), mode="drop")
    )
    owner = jnp.clip(_running_max(mark), 0, C - 1)
    col = jnp.concatenate([jnp.arange(C, dtype=jnp.int32), owner])
    j = jnp.concatenate(
        [jnp.zeros((C,), jnp.int32), jnp.arange(NT, dtype=jnp.int32) - ptr[owner] + 1]
    )
    _, _, sy, _ = _level_tables(rle)[1:]
    lev = lev_c[col]
    safe, n, draw0, bottom0 = _column_head(rle, col, jnp.ones(col.shape, bool), sy[lev])
    top, bottom, valid, drawn_before = _column_runs(rle, safe, n, draw0, bottom0, j)
    valid = valid & (j >= 0) & (j < n)
    cy = _cell_height(rle, jnp.left_shift(1, lev).astype(jnp.float32))
    # Front to back in a column: down from the eye's height below it, up above
    # it (traverse._rank's order; the two groups never meet one ray).
    above = bottom.astype(jnp.float32) * cy > cam.position[1]
    rank = jnp.where(above, 2 * rle.max_elements - 1 - j, j)
    lo1, n1, n2 = _column_planes(rle, cam, pl)
    return _Elements(
        n_pairs=_once(jnp.where(valid, n1[col] + n2[col], 0)),
        cell=_once(ix_c[col] | (iz_c[col] << _XZ_BITS) | (lev << (2 * _XZ_BITS))),
        heights=_once(bottom | (top << _H_BITS) | (rank << (2 * _H_BITS))),
        planes=_once(n1[col] | (lo1[col] << _N_BITS)),
        color=_once(rle.color_ptr[safe].astype(jnp.int32) + drawn_before),
    )


def _pair_rows(rle, cam: Camera, pl: _Planes, el: _Elements, e, k, ok):
    """Rows and walk-order key of pair (element ``e``, its ``k``-th plane) (steps 3-4).

    Returns ``(n_rows, key, first texel)``: ``n_rows = 0`` where the plane does not
    see the element (outside its level's stretch, its slopes or its rows).
    """
    cell, heights, planes = el.cell[e], el.heights[e], el.planes[e]
    n1 = planes & ((1 << _N_BITS) - 1)
    ps = jnp.clip(jnp.where(k < n1, (planes >> _N_BITS) + k, k - n1), 0, pl.hx.shape[0] - 1)
    hx, hz = pl.hx[ps], pl.hz[ps]
    mask = (1 << _XZ_BITS) - 1
    ix, iz, lev = cell & mask, (cell >> _XZ_BITS) & mask, cell >> (2 * _XZ_BITS)
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    ex, ey, ez = cam.position[0], cam.position[1], cam.position[2]
    # The cell's entry and exit along the plane: the DDA's face distances.
    px, pz = hx > 0, hz > 0
    tiny_x, tiny_z = jnp.abs(hx) < 1e-12, jnp.abs(hz) < 1e-12
    inv_x = 1.0 / jnp.where(tiny_x, 1.0, hx)
    inv_z = 1.0 / jnp.where(tiny_z, 1.0, hz)
    fxi = lambda d: (ix + d.astype(jnp.int32)).astype(jnp.float32) * c - ex  # noqa: E731
    fzi = lambda d: (iz + d.astype(jnp.int32)).astype(jnp.float32) * c - ez  # noqa: E731
    t_in_x = jnp.where(tiny_x, -_BIG, fxi(~px) * inv_x)
    t_in_z = jnp.where(tiny_z, -_BIG, fzi(~pz) * inv_z)
    t_out_x = jnp.where(tiny_x, _BIG, fxi(px) * inv_x)
    t_out_z = jnp.where(tiny_z, _BIG, fzi(pz) * inv_z)
    if rle.levels == 1:
        # One level: the map's cells lie between its entry and exit anyway.
        t_lo, t_hi = jnp.float32(0.0), jnp.asarray(cam.far, jnp.float32)
    else:
        t_lo, t_hi = pl.t_level[lev, ps], pl.t_level[lev + 1, ps]
    t_in = jnp.maximum(jnp.maximum(t_in_x, t_in_z), t_lo)
    t_out = jnp.minimum(jnp.minimum(t_out_x, t_out_z), t_hi)
    seen = ok & (t_in <= t_out) & (t_out > t_lo) & (t_in < t_hi)
    # Eq. 4.5 over the cell's corners: the walk's own functions, on this pair's
    # plane (its constants gathered; _slopes and _rows_of read only these).
    hmask = (1 << _H_BITS) - 1
    cy = _cell_height(rle, c)
    y_lo = (heights & hmask).astype(jnp.float32) * cy
    y_hi = (((heights >> _H_BITS) & hmask) + 1).astype(jnp.float32) * cy
    inv_in = 1.0 / jnp.maximum(t_in, _TINY)
    inv_out = 1.0 / jnp.maximum(t_out, jnp.maximum(t_in, _TINY))
    q = _PlaneConsts(
        hx, hz, inv_x, inv_z, t_hi, pl.s_min[ps], pl.s_max[ps], pl.hf[ps], pl.p_num[ps],
        pl.q_num[ps],
    )  # fmt: skip
    s0, s1 = _slopes(q, y_lo, y_hi, ey, inv_in, inv_out)
    r0, r1 = _rows_of(q, s0, s1, camera_basis(cam)[2][1])
    r0 = jnp.maximum(r0, pl.lo[ps].astype(jnp.int32))
    r1 = jnp.minimum(r1, pl.hi[ps].astype(jnp.int32))
    seen = seen & (s0 <= s1) & (r0 < r1)
    X, Z = rle.shape[0], rle.shape[2]
    o_bits = int(np.ceil(np.log2(2 * (X + Z) + 2)))
    ordinal = jnp.where(px, ix, -ix) + jnp.where(pz, iz, -iz) + (X + Z)
    key = (((lev << o_bits) | ordinal) << 7) | (heights >> (2 * _H_BITS))
    return jnp.where(seen, r1 - r0, 0), key, pl.base[ps].astype(jnp.int32) + r0


class RayBuffer(NamedTuple):
    """The scattered ray buffer: each texel's writer, the planes' rows back to back."""

    element: jax.Array  # (T,) int32 writer of each texel (an element index; -1: none)
    base: jax.Array  # (P,) int32 texel of row 0 of each plane (its rows lo .. hi - 1)
    lo: jax.Array  # (P,) int32 first row of each plane
    hi: jax.Array  # (P,) int32 one past its last row


class _ScatterLoop(NamedTuple):
    """State of :func:`scatter_ray_buffer`'s loop over pair windows."""

    start: jax.Array  # () int32, first pair of the next window
    key: jax.Array  # (P rows,) int32 walk-order key of each texel's writer so far
    element: jax.Array  # (P rows,) int32 its element (-1: none)
    rows: jax.Array  # () int32 row updates so far
    steps: jax.Array  # () int32


def scatter_ray_buffer(
    rle,
    cam: Camera,
    seg: Segments,
    planes: jax.Array,
    *,
    rows: int,
    lod_distance,
    window: int,
    texels: int,
):
    """The ray buffer's texels and their writers, drawn column by column (see the module docstring).

    Args:
        rle: a single-object :class:`~jaxgfx.raycast.RLEVolume` (:func:`check_scatter_scene`).
        cam: camera.
        seg: the frame's :class:`Segments`.
        planes: (P,) int32 plane indices, ``arange(P)``.
        rows: static ray-buffer column length.
        lod_distance: () horizontal distance where mip level 1 starts.
        window: static pairs per loop step (rows per step: ``max(4 window, rows)``).
        texels: static size of the texel table: each plane's rows back to back
            (:func:`default_texels`); texels past it are lost (counted).

    Returns:
        ``(texels, elements, stats (4,) int32, steps () int32)``: the ray buffer
        (:class:`RayBuffer`), the per-element words (:class:`_Elements`), the
        frame's pairs / row updates / texels drawn / texels lost, and the loop
        steps.
    """
    pl = _plane_tables(rle, cam, seg, planes, rows=rows, lod=jnp.asarray(lod_distance, jnp.float32))
    el = _flat_elements(rle, cam, pl)
    N = el.n_pairs.shape[0]
    incl = jnp.cumsum(el.n_pairs)
    first_pair = incl - el.n_pairs
    total = incl[-1]
    # A window's rows hold at least one whole pair, so every step moves on.
    Q, R = int(window), max(4 * int(window), rows)
    T = int(texels)
    slot_q = jnp.arange(Q, dtype=jnp.int32)
    slot_r = jnp.arange(R, dtype=jnp.int32)
    ids = jnp.arange(N, dtype=jnp.int32)

    def body(s: _ScatterLoop) -> _ScatterLoop:
        # The window's pairs: element of each slot by a running max of marks.
        rel = first_pair - s.start
        mark = (
            jnp.full((Q,), -1, jnp.int32)
            .at[jnp.where((el.n_pairs > 0) & (rel >= 0), rel, Q)]
            .max(ids, mode="drop")
        )
        head = jnp.searchsorted(incl, s.start, side="right").astype(jnp.int32)
        mark = mark.at[0].max(jnp.minimum(head, N - 1))
        e = jnp.clip(_running_max(mark), 0, N - 1)
        k = s.start + slot_q - first_pair[e]
        ok = s.start + slot_q < total
        n_rows, key, texel0 = _pair_rows(rle, cam, pl, el, e, k, ok)
        # As many whole pairs as the window's rows hold.
        n_rows, key, texel0 = jax.lax.optimization_barrier((n_rows, key, texel0))
        r_incl = jnp.cumsum(n_rows)
        fits = r_incl <= R
        taken = jnp.sum(fits.astype(jnp.int32))
        r_first = r_incl - n_rows
        rmark = (
            jnp.full((R,), -1, jnp.int32)
            .at[jnp.where(fits & (n_rows > 0), r_first, R)]
            .max(slot_q, mode="drop")
        )
        q = jnp.clip(_running_max(rmark), 0, Q - 1)
        live = slot_r < jnp.where(taken > 0, r_incl[jnp.maximum(taken - 1, 0)], 0)
        texel = jnp.where(live, texel0[q] + slot_r - r_first[q], T)
        k_r = key[q]
        texel, k_r = jax.lax.optimization_barrier((texel, k_r))
        table = s.key.at[texel].min(k_r, mode="drop")
        won = live & (table[jnp.minimum(texel, T - 1)] == k_r)
        element = s.element.at[jnp.where(won, texel, T)].set(e[q], mode="drop")
        return _ScatterLoop(
            start=s.start + taken,
            key=table,
            element=element,
            rows=s.rows + jnp.sum(jnp.where(fits, n_rows, 0)),
            steps=s.steps + 1,
        )

    s0 = _ScatterLoop(
        start=jnp.int32(0),
        key=jnp.full((T,), _NO_KEY, jnp.int32),
        element=jnp.full((T,), -1, jnp.int32),
        rows=jnp.int32(0),
        steps=jnp.int32(0),
    )
    s = jax.lax.while_loop(lambda s: s.start < total, body, s0)
    drawn = jnp.sum((s.element >= 0).astype(jnp.int32))
    lost = jnp.maximum(pl.texels - T, 0)
    stats = jnp.stack([total, s.rows, drawn, lost])
    buffer = RayBuffer(s.element, pl.plane_base, pl.plane_lo, pl.plane_hi)
    return buffer, el, stats, s.steps


def warp_texels(
    rle, cam: Camera, seg: Segments, buffer: RayBuffer, el: _Elements, *, neighbors: int = 1
):
    """Displays a scattered ray buffer (4.5.5, Eq. 4.6), as :func:`~.warp.warp_ray_buffer`.

    Every pixel reads its texel's writer and those of the same row in the
    ``neighbors`` planes on either side, and keeps the nearest box its own ray
    enters (the nearest texel's where it enters none).

    Returns:
        ``(color (H, W, 3), depth (H, W), entered (H, W) bool)``.
    """
    T, P = buffer.element.shape[0], buffer.base.shape[0]
    st, i0, cnt, row, ok = _ray_buffer_texel(cam, seg)
    origins, dirs = pixel_rays(cam, normalize=False)
    mask = (1 << _XZ_BITS) - 1
    hmask = (1 << _H_BITS) - 1

    def lookup(di):
        i = jnp.clip(i0 + di, 0, jnp.maximum(cnt - 1, 0))
        plane = jnp.clip(st + i, 0, P - 1)
        texel = buffer.base[plane] + row
        inside = ok & (row >= buffer.lo[plane]) & (row < buffer.hi[plane]) & (texel < T)
        e = jnp.take(buffer.element, jnp.clip(texel, 0, T - 1))
        hit = inside & (e >= 0)
        e = jnp.where(hit, e, 0)
        cell, heights = el.cell[e], el.heights[e]
        box = (
            (heights >> _H_BITS) & hmask,
            heights & hmask,
            cell & mask,
            (cell >> _XZ_BITS) & mask,
            cell >> (2 * _XZ_BITS),
        )
        return hit, e, box

    return _nearest_candidate(
        rle, lookup, lambda e: el.color[e], origins, dirs, neighbors=neighbors
    )


def scatter_frame(rle, cam: Camera, seg: Segments, planes, *, rows: int, lod_distance, settings):
    """One frame's ray buffer scattered and warped (``RenderSettings(traversal="scatter")``).

    ``settings``: the :class:`~jaxgfx.raycast.RenderSettings` (its ``window``,
    ``texels`` and ``neighbors``; None sizes take :func:`default_window` and
    :func:`default_texels`).

    Returns:
        ``((color, depth, entered), stats (4,), steps ())``: :func:`warp_texels`'
        image and :func:`scatter_ray_buffer`'s counts and loop steps.
    """
    P = planes.shape[0]
    window = settings.window or default_window(cam.width, cam.height)
    texels = settings.texels or default_texels(cam.width, cam.height, P, rows)
    check_scatter_scene(rle, P, texels)
    buffer, elements, stats, steps = scatter_ray_buffer(
        rle, cam, seg, planes, rows=rows, lod_distance=lod_distance, window=window, texels=texels
    )
    image = warp_texels(rle, cam, seg, buffer, elements, neighbors=settings.neighbors)
    return image, stats, steps
