"""The per-plane cell walk of the ray caster and its culling bounds (thesis 4.5.4.1, 4.5.4.3).

The 2-D DDA's moves (:func:`_cell_exit`, :func:`_next_cell`, with the jump over
empty squares and the LOD band switch), the per-plane constants and loop state
of :mod:`.traverse`, and the bounds that let a plane skip work without changing
what it draws (not in the thesis): the rows whose rays can still meet the scene
(:func:`_live_rows`) and the cheap step past a column that falls on rows already
drawn (:func:`_free_step`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxgfx._src.camera import Camera, camera_basis
from jaxgfx._src.voxel.codec import unpack_element
from jaxgfx._src.voxel.grid import _cell_height, _level_tables, _map_column

__all__: list[str] = []  # private helpers of traverse.py

_TINY = 1e-6
# Ray-buffer rows a column span's projection is widened by in the free step's
# test: an element inside the span has other corner slopes, and their projection
# may land a rounding error (~1e-4 rows at 1024-row columns) outside the span's.
# A whole row would let through every cell whose column merely touches an open row.
_ROW_EPS = 0.01


# ---------------------------------------------------------------------------
# Coverage rows (4.5.4.3), empty-space boxes, rows that can still meet the scene
# ---------------------------------------------------------------------------


def _row_mask(r0, r1, n_words):
    """(N, n_words) uint32 bit masks of the row ranges ``[r0, r1)``."""
    w = 32 * jnp.arange(n_words, dtype=jnp.int32)[None, :]
    a = jnp.clip(r0[:, None] - w, 0, 32).astype(jnp.uint32)
    b = jnp.clip(r1[:, None] - w, 0, 32).astype(jnp.uint32)
    full = jnp.uint32(0xFFFFFFFF)
    low = lambda n: jnp.where(n >= 32, full, (jnp.uint32(1) << jnp.minimum(n, 31)) - 1)  # noqa: E731
    return jnp.where(b > a, low(b) & ~low(a), jnp.uint32(0))


def _once(x):
    """``x`` (int32 or bool), computed once for all of its users; the same values.

    XLA:CPU fuses cheap element-wise producers into every consumer, so a value
    read by several fused ops (an element's rows by the coverage test, the
    coverage update, the floating horizon and the list slots) is recomputed in
    each, from the element's projection on.  A reduce is never fused into more
    than one consumer: a ``min`` with the type's largest value pins ``x`` in
    memory.
    """
    top = True if x.dtype == jnp.bool_ else jnp.iinfo(x.dtype).max
    return jnp.min(jnp.stack([x, jnp.full_like(x, top)], axis=-1), axis=-1)


def _empty_box(rle, ix, iz, lev, col, has_tile, sx, sz):
    """Cells ``[x0, x1) x [z0, z1)`` around empty cell (ix, iz) known to be empty.

    The square of chessboard radius ``empty_dist - 1``, or the whole tile
    where no instance stands.
    """
    xl, zl = sx[lev], sz[lev]
    safe = jnp.clip(col, 0, rle.empty_dist.shape[0] - 1)
    r = jnp.maximum(rle.empty_dist[safe].astype(jnp.int32) - 1, 0)
    bx0 = jnp.floor_divide(ix, xl) * xl
    bz0 = jnp.floor_divide(iz, zl) * zl
    x0 = jnp.where(has_tile, ix - r, bx0)
    x1 = jnp.where(has_tile, ix + r + 1, bx0 + xl)
    z0 = jnp.where(has_tile, iz - r, bz0)
    z1 = jnp.where(has_tile, iz + r + 1, bz0 + zl)
    return x0, x1, z0, z1


def _scene_top(rle) -> float:
    """Highest y any element of any mip level reaches (a coarse cube-mip level rounds Y up)."""
    return float(
        max(s[1] << (0 if rle.column_mips else lev) for lev, s in enumerate(rle.level_shapes))
    )


def _slopes(consts, y_lo, y_hi, ey, inv_in, inv_out):
    """Slopes ``(s_min, s_max)`` under which heights ``[y_lo, y_hi]`` are seen over a cell.

    The cell spans horizontal distances ``1 / inv_in`` to ``1 / inv_out`` along the
    plane; the extreme slopes are at its corners, clipped to the plane's visible
    slopes (Eq. 4.5's input).  ``s_min > s_max``: not visible.
    """
    c0, c1 = (y_lo - ey) * inv_in, (y_hi - ey) * inv_in
    c2, c3 = (y_lo - ey) * inv_out, (y_hi - ey) * inv_out
    s_min = jnp.maximum(jnp.minimum(jnp.minimum(c0, c1), jnp.minimum(c2, c3)), consts.s_min)
    s_max = jnp.minimum(jnp.maximum(jnp.maximum(c0, c1), jnp.maximum(c2, c3)), consts.s_max)
    return s_min, s_max


def _project(consts, s, fy):
    """Ray-buffer coordinate of slope ``s`` in one plane (Eq. 4.5)."""
    return (consts.p_num + consts.q_num * s) / jnp.maximum(consts.hf + s * fy, 1e-9)


def _rows_of(consts, s_a, s_b, fy, margin=0.0):
    """Rows ``[r0, r1)`` of one plane seen under slopes between ``s_a`` and ``s_b`` (Eq. 4.5).

    The rows whose centres lie between the two slopes' ray-buffer coordinates,
    widened by ``margin`` rows on each side.
    """
    a, b = _project(consts, s_a, fy), _project(consts, s_b, fy)
    r0 = jnp.ceil(jnp.minimum(a, b) - 0.5 - margin).astype(jnp.int32)
    r1 = jnp.floor(jnp.maximum(a, b) - 0.5 + margin).astype(jnp.int32) + 1
    return r0, r1


def _live_rows(consts, ey, t, *, y_top: float, fy):
    """Rows ``[a0, a1)`` of one plane whose rays still meet ``0 <= y <= y_top`` past ``t``.

    Along the plane a row's ray is ``y = ey + s t'`` (``s``: its slope), for
    ``t <= t' <= t_far``; it meets the slab iff ``s`` lies in
    ``[-ey / t_a, (y_top - ey) / t_b]``, where ``t_a`` (``t_b``) is ``t`` when the
    eye is above the floor (below the top) and ``t_far`` otherwise.  The rows come
    from the slopes by Eq. 4.5, as an element's do, so no row an element could
    still draw is left out.
    """
    t_a = jnp.where(ey >= 0, t, consts.t_far)
    t_b = jnp.where(ey <= y_top, t, consts.t_far)
    s_lo = (0.0 - ey) / t_a
    s_hi = (y_top - ey) / t_b
    # A hair wider for rounding (an element's slopes are computed from the
    # voxel heights, not from these bounds); a whole row wider would keep rows
    # no element can reach open to the map's edge.
    tol = 1e-5 * (jnp.abs(s_lo) + jnp.abs(s_hi)) + 1e-7
    s_lo = jnp.maximum(s_lo - tol, consts.s_min)
    s_hi = jnp.minimum(s_hi + tol, consts.s_max)
    a0, a1 = _rows_of(consts, s_lo, s_hi, fy)
    return a0, jnp.where(s_lo <= s_hi, a1, a0)


class _PlaneConsts(NamedTuple):
    """Per-plane constants of the traversal (:func:`_plane_init`), all () float32."""

    hx: jax.Array  # x of the plane's unit x-z direction
    hz: jax.Array  # z of the plane's unit x-z direction
    inv_x: jax.Array  # 1 / hx (guarded)
    inv_z: jax.Array  # 1 / hz (guarded)
    t_far: jax.Array  # horizontal distance where the walk ends (map exit or far plane)
    s_min: jax.Array  # smallest slope dy/dt visible in the plane
    s_max: jax.Array  # largest slope dy/dt visible in the plane
    hf: jax.Array  # camera forward along the plane direction (Eq. 4.5 denominator)
    p_num: jax.Array  # Eq. 4.5 numerator, constant term
    q_num: jax.Array  # Eq. 4.5 numerator, slope term


class _ChunkLoop(NamedTuple):
    """State of :func:`~.traverse.traverse_lists`' chunk loops (per-plane arrays: padded planes)."""

    lists: jax.Array  # (size, 5, K) int32, the chunk's list buffer (reused by every chunk)
    pool: jax.Array  # (5, pool_size) int32, the lists of the pass's committed chunks
    used: jax.Array  # () int32, pool entries taken
    start: jax.Array  # (Pp,) int32, each plane's first pool entry
    drawn: jax.Array  # (Pp,) int32, each plane's entries in the pool
    cov: jax.Array  # (Pp, W) uint32, coverage maps
    first: jax.Array  # (Pp, W) int32, first drawing entry per coverage word
    stats: jax.Array  # (Pp, 4) int32
    steps: jax.Array  # () int32, dependent loop steps
    full: jax.Array  # () bool, a chunk did not fit the pass's pool
    pass_of: jax.Array  # (Pp,) int32, the pass that committed each plane (-1: none yet)
    pass_id: jax.Array  # () int32, the current pass (from 1)


class _PlaneState(NamedTuple):
    """Loop state of one plane in :func:`traverse_planes` (vmap adds a leading plane axis)."""

    ix: jax.Array  # () int32, map cell x at level ``lev``
    iz: jax.Array  # () int32, map cell z at level ``lev``
    lev: jax.Array  # () int32, mip level of the cell
    t: jax.Array  # () float32, horizontal distance where the walk entered the cell
    done: jax.Array  # () bool, plane finished (left the map, far limit, horizon closed)
    lo: jax.Array  # () int32, floating horizon: first row not yet drawn
    hi: jax.Array  # () int32, floating horizon: one past the last row not yet drawn
    cov: jax.Array  # (ceil(rows / 32),) uint32, 1-bit coverage map of the column
    first: jax.Array  # (ceil(rows / 32),) int32, list entry that first drew in each word
    nbuf: jax.Array  # () int32, elements drawn so far (may exceed K: overflow)
    stats: jax.Array  # (3,) int32, elements in visited columns / processed / drawn
    k: jax.Array  # () int32, elements of the current column already handled
    it: jax.Array  # () int32, loop steps taken


def _cell_exit(consts: _PlaneConsts, cam: Camera, ix, iz, lev):
    """Exact 2-D DDA (Amanatides & Woo): ``(cell size, exit t, exit through x?)`` of a cell."""
    hx, hz, big = consts.hx, consts.hz, jnp.float32(1e30)
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    bx = (hx > 0).astype(jnp.int32)
    bz = (hz > 0).astype(jnp.int32)
    nx = ((ix + bx).astype(jnp.float32) * c - cam.position[0]) * consts.inv_x
    nz = ((iz + bz).astype(jnp.float32) * c - cam.position[2]) * consts.inv_z
    nx = jnp.where(jnp.abs(hx) < 1e-12, big, nx)
    nz = jnp.where(jnp.abs(hz) < 1e-12, big, nz)
    return c, jnp.minimum(jnp.minimum(nx, nz), consts.t_far), nx <= nz


def _next_cell(
    rle, consts, cam, ix, iz, lev, c, t_out, go_x, col, has_tile, empty, *, lod_distance
):
    """The cell the walk enters after cell (ix, iz, lev), exited at ``t_out``.

    Returns ``(ix, iz, lev, t, leaves)``: the next cell, the walk's t there and
    whether it lies outside the map.  ``empty``: the cell is known empty, so the
    walk may jump over the empty square around it.
    """
    hx, hz, inv_x, inv_z, t_far = consts.hx, consts.hz, consts.inv_x, consts.inv_z, consts.t_far
    L, _, sx, _, sz = _level_tables(rle)
    ex, ez = cam.position[0], cam.position[2]
    big = jnp.float32(1e30)
    bx = (hx > 0).astype(jnp.int32)
    bz = (hz > 0).astype(jnp.int32)
    ix_n = jnp.where(go_x, ix + 2 * bx - 1, ix)
    iz_n = jnp.where(go_x, iz, iz + 2 * bz - 1)
    # Switch LOD by distance (4.5.4.1): level l from lod_distance * 2^(l-1)
    # on, so a voxel covers about the same screen size in every band.
    band = lod_distance * jnp.left_shift(1, lev).astype(jnp.float32)
    # Empty-space skipping (not in the thesis): most cells a plane crosses are
    # empty, so from an empty cell the DDA jumps to the first cell after the
    # empty square around it (its tile's ``empty_dist``, or the whole tile
    # where no instance stands).  It stops short at the LOD band's end, in
    # the cell holding it, so the non-empty cells visited and the level
    # switches are exactly those of the plain DDA.
    x0, x1, z0, z1 = _empty_box(rle, ix, iz, lev, col, has_tile, sx, sz)
    ex_x = jnp.where(hx > 0, x1, x0).astype(jnp.float32) * c
    ex_z = jnp.where(hz > 0, z1, z0).astype(jnp.float32) * c
    bx_t = jnp.where(jnp.abs(hx) < 1e-12, big, (ex_x - ex) * inv_x)
    bz_t = jnp.where(jnp.abs(hz) < 1e-12, big, (ex_z - ez) * inv_z)
    t_box = jnp.minimum(jnp.minimum(bx_t, bz_t), t_far)
    at_band = t_box >= band
    t_jump = jnp.where(at_band, band, t_box)
    px = jnp.floor((ex + hx * t_jump) / c).astype(jnp.int32)
    pz = jnp.floor((ez + hz * t_jump) / c).astype(jnp.int32)
    # Leaving the box, the exit axis's index is exact; the other comes from
    # the exit point, inside the box.
    box_x = bx_t <= bz_t
    jx = jnp.where(at_band | ~box_x, jnp.clip(px, x0, x1 - 1), jnp.where(hx > 0, x1, x0 - 1))
    jz = jnp.where(at_band | box_x, jnp.clip(pz, z0, z1 - 1), jnp.where(hz > 0, z1, z0 - 1))
    # Entry of the target cell (its near faces), the DDA's t there.
    t_jx = ((jx + 1 - bx).astype(jnp.float32) * c - ex) * inv_x
    t_jz = ((jz + 1 - bz).astype(jnp.float32) * c - ez) * inv_z
    t_jx = jnp.where(jnp.abs(hx) < 1e-12, -big, t_jx)
    t_jz = jnp.where(jnp.abs(hz) < 1e-12, -big, t_jz)
    stays = (jx == ix) & (jz == iz)  # float rounding at the band's end: plain step
    skip = empty & (t_out < band) & (t_out < t_far) & ~stays
    ix_n = jnp.where(skip, jx, ix_n)
    iz_n = jnp.where(skip, jz, iz_n)
    t_out = jnp.where(skip, jnp.maximum(jnp.maximum(t_jx, t_jz), t_out), t_out)
    coarser = (t_out >= band) & (lev < L - 1) & ~skip
    ix_n = jnp.where(coarser, ix_n >> 1, ix_n)
    iz_n = jnp.where(coarser, iz_n >> 1, iz_n)
    lev_n = jnp.where(coarser, lev + 1, lev)
    tx, tz = rle.tiles.shape
    leaves = (ix_n < 0) | (iz_n < 0) | (ix_n >= tx * sx[lev_n]) | (iz_n >= tz * sz[lev_n])
    return ix_n, iz_n, lev_n, t_out, leaves


def _free_step(
    rle, cam: Camera, consts: _PlaneConsts, carry: _PlaneState, *, lod_distance, n_words
):
    """One cheap step of one plane: passes a cell that cannot draw (not in the thesis).

    A cell is passed when it is empty or when its whole column, from the floor
    to the top of its first element (no voxel of the column is higher),
    projects only onto rows already drawn (Eq. 4.5 over the cell's t range,
    ``_ROW_EPS`` wider for rounding): no element of it could pass the coverage
    test, so :func:`_plane_step` would draw nothing there.  This is the
    floating horizon (4.5.4.3) applied to a whole column before its elements
    are decoded; a plane looking across a forest crosses mostly such cells
    (hidden trunks and crowns, gaps), and they cost a few reads each instead
    of a full step.  Other cells, a column part-way done (``k > 0``) and done
    planes are left unchanged.
    """
    L, off, sx, sy, sz = _level_tables(rle)
    _, _, forward = camera_basis(cam)
    ey = cam.position[1]
    ix, iz, lev, t, done = carry.ix, carry.iz, carry.lev, carry.t, carry.done
    c, t_out, go_x = _cell_exit(consts, cam, ix, iz, lev)
    in_map, has_tile, col = _map_column(rle, ix, iz, lev, off, sx, sz)
    inside = in_map & has_tile
    safe = jnp.where(inside, col, 0)
    n = jnp.where(inside, rle.count[safe].astype(jnp.int32), 0)
    skip0 = unpack_element(rle.first[safe].astype(jnp.int32))[0]
    y_hi = (sy[lev] - skip0).astype(jnp.float32) * _cell_height(rle, c)
    inv_in = 1.0 / jnp.maximum(t, _TINY)
    inv_out = 1.0 / jnp.maximum(t_out, jnp.maximum(t, _TINY))
    # Slopes of the column's span [0, y_hi] over the cell, as an element's.
    e_smin, e_smax = _slopes(consts, 0.0, y_hi, ey, inv_in, inv_out)
    r0, r1 = _rows_of(consts, e_smin, e_smax, forward[1], _ROW_EPS)
    r0 = jnp.maximum(r0, carry.lo)
    r1 = jnp.minimum(r1, carry.hi)
    r0, r1 = _once(r0), _once(r1)
    fresh = jnp.any((_row_mask(r0[None], r1[None], n_words)[0] & ~carry.cov) != 0)
    go = ((n == 0) | ~fresh | (e_smin > e_smax)) & ~done & (carry.k == 0)
    ix_n, iz_n, lev_n, t_n, leaves = _next_cell(
        rle,
        consts,
        cam,
        ix,
        iz,
        lev,
        c,
        t_out,
        go_x,
        col,
        has_tile,
        in_map & (n == 0),
        lod_distance=lod_distance,
    )
    new = carry._replace(
        ix=jnp.where(go, ix_n, ix),
        iz=jnp.where(go, iz_n, iz),
        lev=jnp.where(go, lev_n, lev),
        t=jnp.where(go, t_n, t),
        done=done | (go & ((t_n >= consts.t_far) | leaves)),
        stats=carry.stats.at[0].add(jnp.where(go, n, 0)),
    )
    return new, go
