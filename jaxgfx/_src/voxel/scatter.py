"""The ray buffer drawn column by column: every element scattered into the planes that cross it.

The thesis's traversal (4.5.4) walks each plane's cells front to back and keeps,
for every ray-buffer texel, the first element that covers its row.  That writer
is fixed by the walk's order alone: the coverage map and the floating horizon
(4.5.4.3) only skip elements that could not be first anywhere.  So the same ray
buffer comes out of a different loop order, which needs no dependent steps:

1. Every plane is a vertical half-plane through the eye; in the map it is a
   half-line from the eye in its x-z direction.  The planes are sorted by that
   direction once per frame (:func:`~.scatter_planes._plane_tables`).
2. A map cell is crossed by exactly the planes whose direction lies between the
   directions of its corners seen from the eye: one contiguous run of the
   sorted planes, or two where the run wraps behind the eye
   (:func:`~.scatter_planes._column_planes`).  These are the cells each plane's 2-D DDA visits.
3. Each RLE element of each column (:func:`~.scatter_elements._flat_elements`) is paired with the
   planes that cross its cell.  Per pair, the plane's line enters and leaves the
   cell at closed-form distances (the DDA's own arithmetic), clipped to the
   stretch the walk spends at the element's mip level (4.5.4.1); the element's
   corners project to rows with Eq. 4.5 (:func:`_pair_rows`).
4. The walk order of a pair within its plane is a key: mip level, then the cell's
   DDA ordinal (``±ix ± iz``: every DDA step adds one), then the element's
   front-to-back rank in its column.  A scatter-min of the key over the pair's
   rows keeps each texel's first writer, as the rasterizer's z-buffer keeps
   the nearest face; the pairs whose key won a texel write their element there.

Steps 3-4 run over the pairs in windows of a fixed size (``window`` pairs),
their rows drawn ``rows_per_pair`` windows a loop step, into a table of each
plane's on-screen rows back to back, so memory is bounded and a frame takes a
few tens of loop steps, each as wide as a window.  A
frame whose planes have more rows than the table holds draws runs of sorted
planes in turn (passes), each projecting only its planes' pairs.
Elements are the same as the per-plane walk's, and every element in a crossed
cell is projected, while the thousands of dependent one-cell steps are gone.
Of the walk's coverage culling (4.5.4.3) a coarse form stays: a pair whose
rows already hold nearer writers writes no row (:func:`_hidden`, two reads of a
sparse table of block maxima, whatever the pair's height).  Pairs are tested
when their window is taken and, while a window holds more rows than a step
draws, again before every step (tall elements: the heads' columns), so the
row work follows what is still open, as far as the columns' order puts near
elements first.

An instance map's elements are enumerated per tile at the tile's mip level
and gathered a chunk at a time (:mod:`.scatter_elements`), then drawn as above.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, camera_basis
from jaxgfx._src.compaction import compact, running_sum
from jaxgfx._src.voxel.grid import _cell_height, _tail_slots
from jaxgfx._src.voxel.planes import Segments
from jaxgfx._src.voxel.scatter_elements import (
    _N_BITS,
    _flat_elements,
    _instance_chunk,
    _object_elements,
    _pack_runs,
    _slot_runs,
    _tile_levels,
    _unpack_runs,
    default_chunk,
)
from jaxgfx._src.voxel.scatter_planes import _draw_order, _plane_tables, _Planes
from jaxgfx._src.voxel.scatter_warp import (
    _H_BITS,
    _XZ_BITS,
    RayBuffer,
    _Elements,
    _harvest,
    warp_texels,
)
from jaxgfx._src.voxel.walk import _TINY, _PlaneConsts, _rows_of, _slopes

__all__ = [
    "scatter_frame",
    "scatter_ray_buffer",
    "check_scatter_scene",
    "scatter_limits",
    "default_window",
    "default_chunk",
    "rows_per_pair",
    "default_texels",
]

_BIG = np.float32(1e30)
_NO_KEY = np.int32(2**31 - 1)
# Bit fields of the packed per-element words (checked by check_scatter_scene).
_MAX_TEXELS = 1 << 24  # the default table's largest size (two int32 words a texel)
_CULL_BLOCK = 16  # texels per block of the windows' coverage test (_hidden)


def default_texels(width: int, height: int, num_planes: int, rows: int) -> int:
    """Texel table size: 4 per pixel, at most every plane's whole column and ``2^24``.

    A frame with more on-screen plane rows than the table draws them in passes
    (``stats["passes"]``; ``experiments.rle_quality --traversal scatter`` lists
    them per view), the same frame.  Each pass clears the table and reads every
    pixel's writers from it, so the table is sized for the common frame, not
    the largest.
    """
    return int(max(min(num_planes * rows, 4 * width * height, _MAX_TEXELS), 2 * rows))


def default_window(width: int, height: int, *, accelerator: bool = False, frames: int = 1) -> int:
    """Pairs per loop step, a power of two of at least 2^14.

    On the CPU half a frame's pixels, its rows drawn a window at a time
    (:func:`rows_per_pair`).  On an accelerator a step is a kernel launch or
    more and a host sync, so a window is as wide as the device fills: four times
    a frame's pixels (2^20 pairs at 512x384, one or two steps for a frame), and
    at most 2^22 (a step's row arrays, four windows of int32, stay at 64 MB
    each: a 4K frame takes a few steps instead).  Each of the ``frames`` of a
    vectorized batch keeps that window while the batch's step holds at most
    2^23 pairs (row arrays of 128 MB each), so a batch takes the steps of its
    slowest frame, not one more step per frame; a larger batch shares the
    2^23.
    """
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames!r}")
    if not accelerator:
        return 1 << max(14, (width * height // 2 - 1).bit_length())
    # The frame's window rounded up; the batch's share of 2^23 rounded down.
    frame = 1 << (min(4 * width * height, 1 << 22) - 1).bit_length()
    share = 1 << max(0, 23 - (frames - 1).bit_length())
    return max(min(frame, share), 1 << 14)


def rows_per_pair(*, accelerator: bool = False) -> int:
    """A window's rows drawn per loop step, in windows: 1 on the CPU, 4 elsewhere.

    A window's rows are drawn in steps of ``rows_per_pair * window`` rows,
    as many as its pairs have (a far view's pairs cover one or two rows, a
    near one's ten).  A step costs its whole width whatever it holds, so on the
    CPU the steps are a window wide and their count follows the rows; on an
    accelerator, where steps are launches, four windows wide: one step for most
    windows.
    """
    return 1 if not accelerator else 4


def scatter_limits(rle, num_planes: int) -> str | None:
    """None if the scatter traversal takes a map, else which of its limits the map exceeds.

    It takes maps below 16384 columns a side, 4096 voxels high, 8 levels and 64
    elements a column (packed words), with under ``2^31`` element instances (tiles
    times the object's elements, a shared tail counted once per column), seen through
    at most 65535 planes; ``traversal="auto"`` walks a map beyond them wide.

    Args:
        rle: the map (:class:`~jaxgfx.raycast.RLEVolume`).
        num_planes: the frame's planes: ``RenderSettings.num_planes``, else
            :func:`~jaxgfx.raycast.default_num_planes` with the settings and ``rle.shape``.
    """
    X, Y, Z = rle.shape
    if max(X, Z) >= 1 << _XZ_BITS or Y >= 1 << _H_BITS or rle.levels > 8:
        return (
            f"traversal='scatter' takes maps below {1 << _XZ_BITS} columns a side, "
            f"{1 << _H_BITS} voxels high and 8 levels, got {rle.shape}, {rle.levels} levels"
        )
    if 2 * rle.max_elements > 128:
        return f"traversal='scatter' takes columns of at most 64 elements, got {rle.max_elements}"
    if num_planes >= 1 << _N_BITS:
        return f"traversal='scatter' takes at most {(1 << _N_BITS) - 1} planes, got {num_planes}"
    n = int(np.prod(rle.tiles.shape)) * (rle.count.shape[0] + _tail_slots(rle))
    if n >= 1 << 31:
        return f"traversal='scatter' takes fewer than 2^31 element instances, got {n}"
    return None


def check_scatter_scene(rle, num_planes: int, texels: int, rows: int) -> None:
    """Raises ``ValueError`` where :func:`scatter_ray_buffer` cannot draw a scene or table."""
    reason = scatter_limits(rle, num_planes)
    if reason is not None:
        raise ValueError(reason)
    if not 2 * rows <= texels < 2**31:
        raise ValueError(
            f"texels must be at least two ray-buffer columns ({2 * rows}) and below "
            f"2^31, got {texels}"
        )


def _pair_rows(rle, cam: Camera, pl: _Planes, el: _Elements, e, k, ok, planes, p_lo, offset):
    """Rows and walk-order key of pair (element ``e``, its ``k``-th plane in the pass) (steps 3-4).

    ``planes``: the element's plane runs in the pass (``n1 | lo1 << 16``, then
    sorted planes from ``p_lo``); ``offset``: the pass's first texel.

    Returns ``(n_rows, key, first texel)``: ``n_rows = 0`` where the plane does not
    see the element (outside its level's stretch, its slopes or its rows).
    """
    cell, heights = el.cell[e], el.heights[e]
    n1, lo1 = _unpack_runs(planes)
    ps = jnp.where(k < n1, lo1 + k, p_lo + k - n1)
    ps = jnp.clip(ps, 0, pl.packed.shape[0] - 1)
    row = pl.packed[ps]
    hx, hz, s_min, s_max, hf, p_num, q_num, lo, hi = (row[..., i] for i in range(9))
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
        # The stretch at the element's level: selects over the row, not a gather.
        t_lo = t_hi = jnp.float32(0.0)
        for lv in range(rle.levels):
            t_lo = jnp.where(lev == lv, row[..., 9 + lv], t_lo)
            t_hi = jnp.where(lev == lv, row[..., 10 + lv], t_hi)
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
    q = _PlaneConsts(hx, hz, inv_x, inv_z, t_hi, s_min, s_max, hf, p_num, q_num)
    s0, s1 = _slopes(q, y_lo, y_hi, ey, inv_in, inv_out)
    r0, r1 = _rows_of(q, s0, s1, camera_basis(cam)[2][1])
    r0 = jnp.maximum(r0, lo.astype(jnp.int32))
    r1 = jnp.minimum(r1, hi.astype(jnp.int32))
    seen = seen & (s0 <= s1) & (r0 < r1)
    X, Z = rle.shape[0], rle.shape[2]
    o_bits = int(np.ceil(np.log2(2 * (X + Z) + 2)))
    ordinal = jnp.where(px, ix, -ix) + jnp.where(pz, iz, -iz) + (X + Z)
    key = (((lev << o_bits) | ordinal) << 7) | (heights >> (2 * _H_BITS))
    return jnp.where(seen, r1 - r0, 0), key, pl.base[ps] - offset + r0


def _hidden(table, n_rows, key, texel0, *, rows: int):
    """(Q,) bool: the pair's rows already hold writers in front of it, in every texel.

    The table is read in blocks of ``_CULL_BLOCK`` texels (each block's largest
    key) through a sparse table of the blocks' running maxima over 1, 2, 4, ..
    blocks, so a pair of any height (at most ``rows`` texels, static) costs two
    reads: a pair all of whose blocks hold only smaller keys cannot win a texel
    and writes no row.  The walk's coverage test (4.5.4.3), done per loop step
    instead of per cell: which pairs it catches depends on the order the
    columns come in, what the frame shows does not.
    """
    T = table.shape[0]
    nb = -(-T // _CULL_BLOCK)
    padded = jnp.pad(table, (0, nb * _CULL_BLOCK - T), constant_values=_NO_KEY)
    levels = [jnp.max(padded.reshape(nb, _CULL_BLOCK), axis=1)]
    # A pair spans at most rows // _CULL_BLOCK + 2 blocks.
    while (1 << len(levels)) < -(-rows // _CULL_BLOCK) + 2:
        h = 1 << (len(levels) - 1)
        last = levels[-1]
        levels.append(jnp.maximum(last, jnp.pad(last[h:], (0, h), constant_values=_NO_KEY)))
    sparse = jnp.concatenate(levels)
    a = jnp.clip(texel0, 0, T - 1) // _CULL_BLOCK
    b = jnp.clip(texel0 + n_rows - 1, 0, T - 1) // _CULL_BLOCK
    span = jnp.maximum(b - a + 1, 1)
    j = 31 - jax.lax.clz(span)  # floor(log2(span))
    j = jnp.minimum(j, len(levels) - 1)
    lo = sparse[j * nb + a]
    hi = sparse[j * nb + jnp.maximum(b - (1 << j) + 1, a)]
    return (span <= 1 << len(levels)) & (jnp.maximum(lo, hi) < key)


class _Window(NamedTuple):
    """A window's pairs (:func:`scatter_ray_buffer`); (window,) int32 arrays."""

    element: jax.Array
    n_rows: jax.Array  # rows it writes (0: unseen or hidden)
    key: jax.Array  # walk-order key
    texel0: jax.Array  # its first texel
    r_incl: jax.Array  # inclusive prefix of n_rows


class _ScatterLoop(NamedTuple):
    """State of :func:`scatter_ray_buffer`'s loop: a step draws rows of the current window."""

    start: jax.Array  # () int32, first pair of the next window
    key: jax.Array  # (texels,) int32 walk-order key of each texel's writer so far
    element: jax.Array  # (texels,) int32 its element (-1: none)
    rows: jax.Array  # () int32 row updates so far
    steps: jax.Array  # () int32
    window: _Window  # the current window
    drawn: jax.Array  # () int32 its rows drawn


class _Passes(NamedTuple):
    """State of :func:`scatter_ray_buffer`'s loop over passes."""

    passes: jax.Array  # () int32 passes drawn
    candidates: jax.Array  # (2 neighbors + 1, H, W) int32 writers from the passes before
    element: jax.Array  # (texels,) int32 writer of each texel of the last pass (-1: none)
    counts: jax.Array  # (3,) int32 pairs, row updates, texels drawn
    steps: jax.Array  # () int32 window steps


def _pass_planes(el: _Elements, p_lo, p_hi):
    """Each element's plane runs cut to the sorted planes ``p_lo .. p_hi - 1``.

    Returns ``(n_pairs, planes)`` (N,) int32, ``planes`` as :class:`_Elements`'
    (the second run then starts at ``p_lo``).
    """
    n1, lo1 = _unpack_runs(el.planes)
    a1 = jnp.maximum(lo1, p_lo)
    m1 = jnp.maximum(jnp.minimum(lo1 + n1, p_hi) - a1, 0)
    m2 = jnp.maximum(jnp.minimum(el.n_pairs - n1, p_hi) - p_lo, 0)
    n_pairs = jnp.where(el.n_pairs > 0, m1 + m2, 0)
    return n_pairs, _pack_runs(m1, jnp.minimum(a1, p_hi))


def scatter_ray_buffer(
    rle,
    cam: Camera,
    seg: Segments,
    planes: jax.Array,
    *,
    rows: int,
    lod_distance,
    window: int,
    rows_per_pair: int = 1,
    texels: int,
    neighbors: int = 1,
    chunk: int = 1 << 14,
):
    """Each pixel's ray-buffer texel writers, drawn column by column (see the module docstring).

    The planes' rows lie back to back in direction order.  Where they are more
    than the ``texels`` table holds, runs of sorted planes are drawn in turn
    (passes), each pass's pairs the elements' planes in the run, so a frame's
    pairs are projected once whatever the table size.

    Args:
        rle: an :class:`~jaxgfx.raycast.RLEVolume` (:func:`check_scatter_scene`).
        cam: camera.
        seg: the frame's :class:`Segments`.
        planes: (P,) int32 plane indices, ``arange(P)``.
        rows: static ray-buffer column length.
        lod_distance: () horizontal distance where mip level 1 starts.
        window: static pairs per loop step.
        rows_per_pair: static rows per step, in windows (:func:`rows_per_pair`).
        texels: static size of the texel table (:func:`default_texels`), at least
            ``2 rows``: a pass draws planes whose rows start in its first
            ``texels - rows``.
        neighbors: static planes on either side whose writers each pixel keeps.
        chunk: static element instances of an instance map gathered at once
            (:func:`default_chunk`).

    Returns:
        ``(buffer, elements, stats (4,) int32, steps () int32, passes () int32)``:
        the ray buffer (:class:`RayBuffer`: the last pass's texels, and every
        pixel's writers from the earlier passes); the per-element words
        (:class:`_Elements`; an instance map's: the object's, cells in its own
        tile); the frame's pairs / row updates / texels drawn / 0 (no texel is
        lost); the loop steps (windows, and an instance map's chunks); the passes.
    """
    pl = _plane_tables(rle, cam, seg, planes, rows=rows, lod=jnp.asarray(lod_distance, jnp.float32))
    instanced = tuple(rle.tiles.shape) != (1, 1)
    if instanced:
        el, _ = _object_elements(rle, cam)
        tl = _tile_levels(rle, cam, pl, el)
        E = int(chunk)
        n_chunks = (tl.incl[-1] + E - 1) // E
        # Most frames take one chunk: built once, drawn in every pass.
        chunk0 = _instance_chunk(rle, cam, pl, el, tl, 0, E)
    else:
        el = _flat_elements(rle, cam, pl)
        E = el.n_pairs.shape[0]
        draw = _draw_order(rle, cam, E)
    Q, R = int(window), int(rows_per_pair) * int(window)
    T = int(texels)
    span = T - rows  # a pass's planes start in its first ``span`` texels
    slot_q = jnp.arange(Q, dtype=jnp.int32)
    slot_r = jnp.arange(R, dtype=jnp.int32)
    pad = jnp.zeros((Q,), jnp.int32)

    def window_step(ce, ids, p_lo, offset, order, first_pair, incl, total, planes_g):
        def pairs(s: _ScatterLoop) -> _Window:
            """The next window's pairs: element of each slot by a running max of
            marks over the window's elements (the first holds pair ``start``)."""
            head = jnp.searchsorted(incl, s.start, side="right").astype(jnp.int32)
            firsts = jax.lax.dynamic_slice(first_pair, (head,), (Q,))
            c = head + _slot_runs(firsts, jnp.ones((Q,), bool), 0, s.start, Q)
            e = order[c]
            k = s.start + slot_q - first_pair[c]
            ok = s.start + slot_q < total
            n_rows, key, texel0 = _pair_rows(rle, cam, pl, ce, e, k, ok, planes_g[c], p_lo, offset)
            n_rows, key, texel0 = jax.lax.optimization_barrier((n_rows, key, texel0))
            writer = e if ids is None else ids[e]
            # ``r_incl`` (here: no pair begun) is set by the coverage test that follows.
            return _Window(writer, n_rows, key, texel0, n_rows)

        def body(s: _ScatterLoop) -> _ScatterLoop:
            # One loop, R rows a step: a window's pairs are taken when the rows
            # of the one before are drawn (a nested loop would step a vmapped
            # batch by its frames' largest row count in every window).
            new = s.drawn >= s.window.r_incl[-1]
            w = jax.lax.cond(new, pairs, lambda s: s.window, s)
            rs = jnp.where(new, 0, s.drawn)

            def cull(w: _Window) -> _Window:
                # The pairs not begun yet, against the table so far.
                later = w.r_incl - w.n_rows >= rs
                hidden = later & _hidden(s.key, w.n_rows, w.key, w.texel0, rows=rows)
                n_rows = jnp.where(hidden, 0, w.n_rows)
                return w._replace(n_rows=n_rows, r_incl=running_sum(n_rows))

            # A new window's pairs are tested against the windows before; so
            # are a window's pairs not begun yet while it has more than this
            # step's rows left (tall elements: those behind the rows just
            # drawn write none).
            w = jax.lax.cond(new | (w.r_incl[-1] - rs > R), cull, lambda w: w, w)
            # Row ``rs + i``'s pair by a running max of marks (the first holds
            # the pair that row ``rs`` is in).
            r_first = w.r_incl - w.n_rows
            first = jnp.searchsorted(w.r_incl, rs, side="right").astype(jnp.int32)
            q = jnp.clip(_slot_runs(r_first, w.n_rows > 0, first, rs, R), 0, Q - 1)
            row = rs + slot_r
            live = row < w.r_incl[-1]
            texel = jnp.where(live, w.texel0[q] + row - r_first[q], T)
            k_r = w.key[q]
            texel, k_r = jax.lax.optimization_barrier((texel, k_r))
            table = s.key.at[texel].min(k_r, mode="drop")
            won = live & (table[jnp.minimum(texel, T - 1)] == k_r)
            element = s.element.at[jnp.where(won, texel, T)].set(w.element[q], mode="drop")
            return _ScatterLoop(
                start=jnp.where(new, s.start + Q, s.start),
                key=table,
                element=element,
                rows=s.rows + jnp.clip(w.r_incl[-1] - rs, 0, R),
                steps=s.steps + 1,
                window=w,
                drawn=rs + R,
            )

        return body

    def draw_elements(ce: _Elements, ids, draw, p_lo, p_hi, offset, key, element):
        """Draws elements ``ce`` (``draw``: their order) into the pass's texel table.

        Returns ``(key, element, pairs, row updates, steps)``.
        """
        n_pairs, planes_g = _pass_planes(ce, p_lo, p_hi)
        # The elements with pairs in the pass, compacted (and padded by a window
        # of none): a window of Q pairs spans at most Q of them, so a step's
        # work is the window's, not the scene's.
        has = n_pairs > 0
        live = jnp.arange(E) < jnp.sum(has.astype(jnp.int32))
        order = draw[compact(has[draw], E, 0)]
        order = jnp.concatenate([order, pad])
        n_c = jnp.concatenate([jnp.where(live, n_pairs[order[:E]], 0), pad])
        incl = running_sum(n_c)
        first_pair = incl - n_c
        total = incl[-1]
        body = window_step(ce, ids, p_lo, offset, order, first_pair, incl, total, planes_g[order])
        s0 = _ScatterLoop(
            start=jnp.int32(0),
            key=key,
            element=element,
            rows=jnp.int32(0),
            steps=jnp.int32(0),
            window=_Window(*(jnp.zeros((Q,), jnp.int32) for _ in range(5))),
            drawn=jnp.int32(0),
        )
        s = jax.lax.while_loop(
            lambda s: (s.start < total) | (s.drawn < s.window.r_incl[-1]), body, s0
        )
        return s.key, s.element, total, s.rows, s.steps

    def buffer(ps: _Passes, offset) -> RayBuffer:
        return RayBuffer(ps.element, offset, pl.plane_base, pl.plane_rows, ps.candidates)

    def one_pass(ps: _Passes) -> _Passes:
        offset = ps.passes * span
        # The pass before's writers, kept per pixel before its texels are redrawn.
        candidates = jax.lax.cond(
            ps.passes > 0,
            lambda: _harvest(cam, seg, buffer(ps, offset - span), span),
            lambda: ps.candidates,
        )
        # Planes without rows (sorted last, first texel at the end) cross no cell.
        p_lo = jnp.searchsorted(pl.first, offset, side="left").astype(jnp.int32)
        p_hi = jnp.searchsorted(pl.first, offset + span, side="left").astype(jnp.int32)
        key0 = jnp.full((T,), _NO_KEY, jnp.int32)
        element0 = jnp.full((T,), -1, jnp.int32)
        if not instanced:
            out = draw_elements(el, None, draw, p_lo, p_hi, offset, key0, element0)
            key, element, *counts = out
        else:
            # The element instances in chunks of E, near tiles first; every
            # chunk draws into the same table.
            def one_chunk(c):
                ce, ids = jax.lax.cond(
                    c[0] == 0,
                    lambda: chunk0,
                    lambda: _instance_chunk(rle, cam, pl, el, tl, c[0] * E, E),
                )
                out = draw_elements(ce, ids, slot_e, p_lo, p_hi, offset, c[1], c[2])
                return (c[0] + 1, *out[:2], *(a + b for a, b in zip(c[3:], out[2:])))

            zero = jnp.int32(0)
            c0 = (zero, key0, element0, zero, zero, zero)
            c = jax.lax.while_loop(lambda c: c[0] < n_chunks, one_chunk, c0)
            key, element, *counts = c[1:]
        del key
        total, rows_drawn, steps = counts
        drawn = jnp.sum((element >= 0).astype(jnp.int32))
        return _Passes(
            passes=ps.passes + 1,
            candidates=candidates,
            element=element,
            counts=ps.counts + jnp.stack([total, rows_drawn, drawn]),
            steps=ps.steps + steps + (n_chunks if instanced else 0),
        )

    slot_e = jnp.arange(E, dtype=jnp.int32)
    n_passes = jnp.maximum((pl.texels + span - 1) // span, 1)
    p0 = _Passes(
        passes=jnp.int32(0),
        candidates=jnp.full((2 * neighbors + 1, cam.height, cam.width), -1, jnp.int32),
        element=jnp.full((T,), -1, jnp.int32),
        counts=jnp.zeros((3,), jnp.int32),
        steps=jnp.int32(0),
    )
    ps = jax.lax.while_loop(lambda ps: ps.passes < n_passes, one_pass, p0)
    stats = jnp.concatenate([ps.counts, jnp.zeros((1,), jnp.int32)])
    return buffer(ps, (ps.passes - 1) * span), el, stats, ps.steps, ps.passes


def scatter_frame(
    rle, cam: Camera, seg: Segments, planes, *, rows: int, lod_distance, settings, frames: int = 1
):
    """One frame's ray buffer scattered and warped (``RenderSettings(traversal="scatter")``).

    ``settings``: the :class:`~jaxgfx.raycast.RenderSettings` (its ``window``,
    ``texels`` and ``neighbors``; None sizes take :func:`default_window` and
    :func:`default_texels`).  The CPU's and the accelerators' row steps
    (:func:`rows_per_pair`) and, without a ``window``, default windows
    (``frames``: the frames of the vectorized batch this frame is one of) are
    chosen when the program is lowered.

    Returns:
        ``((color, depth, entered), stats (4,), steps (), passes ())``:
        :func:`warp_texels`' image and :func:`scatter_ray_buffer`'s counts, loop
        steps and passes.
    """
    P = planes.shape[0]
    texels = settings.texels or default_texels(cam.width, cam.height, P, rows)
    check_scatter_scene(rle, P, texels, rows)

    def draw(sizes, rle, cam, seg, planes, lod_distance):
        return scatter_ray_buffer(
            rle,
            cam,
            seg,
            planes,
            rows=rows,
            lod_distance=lod_distance,
            window=sizes[0],
            rows_per_pair=sizes[1],
            texels=texels,
            neighbors=settings.neighbors,
            chunk=settings.chunk or default_chunk(cam.width, cam.height),
        )

    # Only the traversal depends on the window and its row steps; the warp is
    # traced once.
    args = (rle, cam, seg, planes, lod_distance)
    window = settings.window
    on_cpu = (window or default_window(cam.width, cam.height), rows_per_pair())
    elsewhere = (
        window or default_window(cam.width, cam.height, accelerator=True, frames=frames),
        rows_per_pair(accelerator=True),
    )
    drawn = jax.lax.platform_dependent(
        *args,
        cpu=functools.partial(draw, on_cpu),
        default=functools.partial(draw, elsewhere),
    )
    buffer, elements, stats, steps, passes = drawn
    return warp_texels(rle, cam, seg, buffer, elements), stats, steps, passes
