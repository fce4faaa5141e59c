"""The scatter's planes (steps 1-2 of :mod:`.scatter`): sorted by direction; the cells they cross.

Every ray-buffer plane is a vertical half-plane through the eye; in the map it is
a half-line from the eye in its x-z direction.  Sorted by that direction
(:func:`_plane_tables`, the per-plane walk's constants, 4.5.3), the planes
that cross a map cell are one run of them, or two across the back direction
(:func:`_column_planes`): exactly the cells each plane's 2-D DDA visits (4.5.4).
The columns are drawn near ones first (:func:`_draw_order`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, camera_basis
from jaxgfx._src.compaction import running_sum
from jaxgfx._src.voxel.planes import Segments
from jaxgfx._src.voxel.walk import _cell_exit, _once, _plane_init
from jaxgfx._src.voxel.wide import _once_f

__all__: list[str] = []


class _Planes(NamedTuple):
    """Per-plane data in direction order (:func:`_plane_tables`); (P,) arrays unless noted."""

    angle: jax.Array  # direction about the reference (_pseudo_angle), ascending; inf: no rows
    n_live: jax.Array  # () planes with rows
    ref: jax.Array  # (2,) reference x-z direction of the angles
    base: jax.Array  # int32 texel index of the plane's row 0 (its rows are back to back)
    texels: jax.Array  # () int32, the frame's texels (sum of the planes' rows)
    first: jax.Array  # (P,) int32 first texel of each plane, ascending
    plane_base: jax.Array  # (P,) int32 ``base`` in plane order
    plane_rows: jax.Array  # (P,) int32 ``lo | hi << 16`` in plane order (``hi = lo``: no rows)
    # (P, 10 + levels) float32, a row a plane: the walk's constants hx, hz, s_min,
    # s_max, hf, p_num, q_num; its rows lo, hi (one past the last); t_level (levels
    # + 1: where the walk enters each mip level, last t_far)
    packed: jax.Array
    # (2, K, levels, P) float32 t_level's min / max sparse tables (K = 1 for one level)
    stretch: jax.Array
    # The live angles' range cut into B equal buckets (_plane_rank): (B + 1,) int32
    # live planes below each bucket; (3,) float32 the range's least angle, buckets
    # per unit of angle, its greatest angle; () int32 search steps a bucket needs
    bucket: jax.Array
    bucket_frame: jax.Array
    bucket_steps: jax.Array


def _plane_tables(rle, cam: Camera, seg: Segments, planes, *, rows: int, lod) -> _Planes:
    """Each plane's constants (:func:`~.walk._plane_init`), sorted by x-z direction (step 1)."""
    consts, c0 = jax.vmap(lambda p: _plane_init(rle, cam, seg, p, rows=rows, n_words=1))(planes)
    L = rle.levels
    ex, ez = cam.position[0], cam.position[2]
    hx, hz = consts.hx, consts.hz
    # A plane's DDA switches to level l (4.5.4.1) at the exit of its first
    # level-(l-1) cell that it leaves past lod 2^(l-1), into the parent of the
    # cell across that exit: followed here cell by cell, in integers, since the
    # level's first cell starts on a cell boundary.
    t_lev = [c0.t]
    ix, iz = c0.ix, c0.iz  # the walk's first cell (clipped into the map)
    exit_cell = jax.vmap(_cell_exit, in_axes=(0, None, 0, 0, None))
    for lev in range(1, L):
        band = lod * float(2 ** (lev - 1))
        _, t0_out, go_x0 = exit_cell(consts, cam, ix, iz, lev - 1)
        # Not out of the level's first cell yet: the cell holding the band's end.
        c = float(2 ** (lev - 1))
        xl, zl = _map_level_shape(rle, lev - 1)
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
        live, _pseudo_angle(ref[0] * hz - ref[1] * hx, ref[0] * hx + ref[1] * hz), jnp.inf
    )
    order = jnp.argsort(angle)
    # The texels: each plane's rows [lo, hi) back to back, in direction order
    # (a pass over a run of sorted planes draws a run of texels).
    n_rows = jnp.where(live, c0.hi - c0.lo, 0)[order]
    first = jnp.cumsum(n_rows) - n_rows
    base = first - jnp.where(live, c0.lo, 0)[order]
    position = jnp.zeros_like(order).at[order].set(jnp.arange(order.shape[0], dtype=order.dtype))
    t_level = jnp.stack(t_lev)[:, order].astype(jnp.float32)
    # A pair reads all of its plane's constants: one row gather, not a dozen
    # (pinned, see walk._once: a per-pair gather would recompute the table's
    # whole set-up for every pair otherwise).
    columns = [hx, hz, consts.s_min, consts.s_max, consts.hf, consts.p_num, consts.q_num]
    columns += [jnp.where(live, c0.lo, 0), jnp.where(live, c0.hi, 0)]
    packed = jnp.concatenate(
        [jnp.stack([c.astype(jnp.float32)[order] for c in columns], axis=1), t_level.T], axis=1
    )
    # Each level's stretches as sparse tables (2^k planes from each plane on):
    # the least start and greatest end over any run of planes in two reads
    # (_run_stretch; one level needs none).
    live_s = jnp.isfinite(angle[order])[None, :]
    tabs = [[jnp.where(live_s, t_level[:-1], jnp.inf)], [jnp.where(live_s, t_level[1:], -jnp.inf)]]
    P = order.shape[0]
    for k in range(1, P.bit_length() if L > 1 else 1):
        h = 1 << (k - 1)
        for tab, op, fill in ((tabs[0], jnp.minimum, jnp.inf), (tabs[1], jnp.maximum, -jnp.inf)):
            prev = tab[-1]
            shifted = jnp.concatenate([prev[:, h:], jnp.full((L, h), fill, jnp.float32)], axis=1)
            tab.append(op(prev, shifted))
    n_live = jnp.sum(live.astype(jnp.int32))
    bucket, frame, steps = _plane_buckets(angle[order], n_live)
    return _Planes(
        angle=angle[order],
        n_live=n_live,
        ref=ref,
        base=_once(base),
        texels=jnp.sum(n_rows),
        first=first,
        plane_base=_once(base[position]),
        plane_rows=_once(c0.lo | ((c0.lo + n_rows[position]) << 16)),
        packed=_once_f(packed),
        stretch=jnp.stack([jnp.stack(tabs[0]), jnp.stack(tabs[1])]),
        bucket=bucket,
        bucket_frame=frame,
        bucket_steps=steps,
    )


def _plane_buckets(angle, n_live):
    """The sorted live angles' range in ``2 P`` equal buckets, for :func:`_plane_rank`.

    Returns ``(bucket, frame, steps)``: (B + 1,) int32 the live planes whose
    bucket lies below each one (``bucket[B] = n_live``); (3,) float32 the least
    live angle, buckets per unit of angle and the greatest live angle; ()
    int32 the binary-search steps the fullest bucket needs.
    """
    P = angle.shape[0]
    B = 2 * P
    live = jnp.arange(P) < n_live
    a_lo = jnp.where(n_live > 0, angle[0], 0.0)
    a_hi = jnp.where(n_live > 0, angle[jnp.maximum(n_live - 1, 0)], 0.0)
    scale = B / jnp.maximum(a_hi - a_lo, 1e-30)
    frame = jnp.stack([a_lo, scale, a_hi]).astype(jnp.float32)
    k = _bucket_of(frame, angle, B)
    counts = jnp.zeros((B,), jnp.int32).at[jnp.where(live, k, B)].add(1, mode="drop")
    bucket = jnp.concatenate([jnp.zeros((1,), jnp.int32), running_sum(counts)])
    steps = 32 - jax.lax.clz(jnp.max(counts))  # bit length: ceil(log2(count + 1))
    return bucket, frame, steps


def _bucket_of(frame, a, B: int):
    """Bucket of angles ``a`` (clipped to the range's): the planes' and the queries' alike."""
    k = jnp.floor((jnp.clip(a, frame[0], frame[2]) - frame[0]) * frame[1])
    return jnp.clip(k, 0, B - 1).astype(jnp.int32)


def _plane_rank(pl: _Planes, q, right):
    """``searchsorted(pl.angle[:n_live], q, side)``, ``side`` "right" where ``right``.

    A query's rank lies between its bucket's first plane and the next bucket's
    (the same monotone bucket function for planes and queries), so a binary
    search over that bucket alone settles it: ``pl.bucket_steps`` steps, a few
    where ``jnp.searchsorted`` takes ``log2 P`` (each a pass over the queries).

    Args:
        q: (...) float32 angles; right: bool, broadcastable to ``q``.

    Returns:
        (...) int32.
    """
    B = pl.bucket.shape[0] - 1
    k = _bucket_of(pl.bucket_frame, q, B)
    lo, hi = pl.bucket[k], pl.bucket[k + 1]
    below = q < pl.bucket_frame[0]
    above = (q > pl.bucket_frame[2]) | (right & (q == pl.bucket_frame[2]))

    def step(_, c):
        lo, hi = c
        mid = (lo + hi) >> 1
        a = pl.angle[jnp.minimum(mid, pl.angle.shape[0] - 1)]
        go = (lo < hi) & ((a < q) | (right & (a == q)))
        return jnp.where(go, mid + 1, lo), jnp.where(go | (lo >= hi), hi, mid)

    lo, _ = jax.lax.fori_loop(0, pl.bucket_steps, step, (lo, hi))
    return jnp.where(below, 0, jnp.where(above, pl.n_live, lo))


def _column_cells(rle):
    """Per pointer-map entry (C,): its map cell ``(ix, iz, level)``; static NumPy arrays."""
    C = rle.count.shape[0]
    offs = np.asarray(rle.level_offsets, np.int64)
    lev = (np.searchsorted(offs, np.arange(C), side="right") - 1).astype(np.int64)
    zl = np.asarray([s[2] for s in rle.level_shapes], np.int64)[lev]
    q = np.arange(C) - offs[lev]
    return (q // zl).astype(np.int32), (q % zl).astype(np.int32), lev.astype(np.int32)


def _map_level_shape(rle, lev: int) -> tuple[int, int]:
    """Map cells ``(x, z)`` of mip level ``lev``: the object's times the instance tiles."""
    tx, tz = rle.tiles.shape
    xl, _, zl = rle.level_shapes[lev]
    return tx * xl, tz * zl


def _pseudo_angle(v, u):
    """The direction ``(u, v)`` as a number in ``[-2, 2]`` that grows with ``atan2(v, u)``.

    The diamond angle: the same order as the angle (all that sorting the planes
    and bracketing a cell's corners need) at a division instead of an ``atan2``,
    which XLA:CPU evaluates far more slowly.  A half turn is exactly 2: the
    opposite of a direction at or above the reference is its value less 2.
    """
    s = jnp.abs(u) + jnp.abs(v)
    r = 1.0 - u / jnp.where(s > 0, s, 1.0)
    return jnp.where(v >= 0, r, -r)


def _corner_angle(pl: _Planes, dx, dz):
    """Direction of the map point ``(dx, dz)`` from the eye, as the planes' ``angle``."""
    rx, rz = pl.ref[0], pl.ref[1]
    return _pseudo_angle(rx * dz - rz * dx, rx * dx + rz * dz)


def _box_corners(pl: _Planes, x0, z0, x1, z1):
    """(4, ...) the directions of boxes' corners (:func:`_corner_angle`)."""
    pairs = ((x0, z0), (x1, z0), (x0, z1), (x1, z1))
    return jnp.stack([_corner_angle(pl, a, b) for a, b in pairs])


def _run_stretch(pl: _Planes, lev, a, n):
    """Least start and greatest end of level ``lev``'s stretch over planes ``a .. a + n - 1``.

    ``(inf, -inf)`` where ``n = 0``.
    """
    P = pl.stretch.shape[-1]
    m = jnp.maximum(n, 1)
    k = 31 - jax.lax.clz(m.astype(jnp.int32))
    a_c = jnp.clip(a, 0, P - 1)
    b_c = jnp.clip(a + m - jnp.left_shift(1, k), 0, P - 1)
    t_lo = jnp.minimum(pl.stretch[0, k, lev, a_c], pl.stretch[0, k, lev, b_c])
    t_hi = jnp.maximum(pl.stretch[1, k, lev, a_c], pl.stretch[1, k, lev, b_c])
    return jnp.where(n > 0, t_lo, jnp.inf), jnp.where(n > 0, t_hi, -jnp.inf)


def _box_planes(rle, pl: _Planes, corner, x0, z0, x1, z1, lev):
    """The sorted planes that cross map boxes (step 2): ``(lo1, n1, n2)`` int32.

    Args:
        corner: (4, ...) the boxes' corner directions (:func:`_corner_angle`).
        x0, z0, x1, z1: the boxes' extent relative to the eye, in level-0 voxels.
        lev: the mip level the boxes are drawn at (only the planes' stretch at
            that level crosses them).

    Returns:
        Planes ``lo1 .. lo1 + n1 - 1`` and, where the box's directions wrap past
        the back of the eye, ``0 .. n2 - 1`` too.
    """
    a0, a1 = jnp.min(corner, axis=0), jnp.max(corner, axis=0)
    # A box seen under more than a half turn lies across the back direction:
    # its directions run from its corners' least angle >= 0 up to the back (2),
    # and from -2 up to their greatest angle < 0.
    wrap = (a1 - a0) > 2.0
    w0 = jnp.min(jnp.where(corner >= 0, corner, np.inf), axis=0)
    w1 = jnp.max(jnp.where(corner < 0, corner, -np.inf), axis=0)
    # The three searches as one (the left one first).
    q = jnp.stack([jnp.where(wrap, w0, a0), jnp.where(wrap, 2.0, a1), w1])
    right = jnp.asarray([False, True, True]).reshape((3,) + (1,) * (q.ndim - 1))
    lo1, hi1, hi2 = _plane_rank(pl, q, right)
    hi2 = jnp.where(wrap, hi2, 0)
    # The eye's own box: every plane starts in it.
    eye = (x0 <= 0) & (x1 >= 0) & (z0 <= 0) & (z1 >= 0)
    if rle.levels > 1:
        # (only where some plane starts its walk at this level)
        eye = eye & (_run_stretch(pl, lev, 0, pl.n_live)[0] <= 0.0)
    lo1 = jnp.where(eye, 0, lo1)
    n1 = jnp.maximum(jnp.where(eye, pl.n_live, jnp.minimum(hi1, pl.n_live)) - lo1, 0)
    n2 = jnp.where(eye, 0, jnp.minimum(hi2, pl.n_live))
    if rle.levels == 1:
        return lo1, n1, n2
    # A box that none of its planes spends its level's stretch over draws
    # nothing (a plane entering the map far away starts at level 0 there: the
    # stretches of all planes together would keep most boxes).
    lo_a, hi_a = _run_stretch(pl, lev, lo1, n1)
    lo_b, hi_b = _run_stretch(pl, lev, 0, n2)
    t_lo, t_hi = jnp.minimum(lo_a, lo_b), jnp.maximum(hi_a, hi_b)
    near = jnp.hypot(jnp.maximum(jnp.maximum(x0, -x1), 0.0), jnp.maximum(jnp.maximum(z0, -z1), 0.0))
    far = jnp.hypot(jnp.maximum(jnp.abs(x0), jnp.abs(x1)), jnp.maximum(jnp.abs(z0), jnp.abs(z1)))
    reach = (far >= t_lo) & (near <= t_hi)
    return lo1, jnp.where(reach, n1, 0), jnp.where(reach, n2, 0)


def _column_planes(rle, cam: Camera, pl: _Planes):
    """Per pointer-map entry of a single-object map: the sorted planes that cross its cell.

    Returns ``(lo1, n1, n2)`` (C,) int32 (:func:`_box_planes`).
    """
    ix_n, iz_n, lev_n = _column_cells(rle)
    ix, iz, lev = (jnp.asarray(a) for a in (ix_n, iz_n, lev_n))
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    ex, ez = cam.position[0], cam.position[2]
    x0 = ix.astype(jnp.float32) * c - ex
    z0 = iz.astype(jnp.float32) * c - ez
    # The direction of every cell corner once (neighbouring cells share them),
    # each level's corner grid flat, then each cell's four corners gathered.
    grids, offs = [], [0]
    for lev_l, (xl, _, zl) in enumerate(rle.level_shapes):
        cl = np.float32(2**lev_l)
        dx = jnp.arange(xl + 1, dtype=jnp.float32)[:, None] * cl - ex
        dz = jnp.arange(zl + 1, dtype=jnp.float32)[None, :] * cl - ez
        grids.append(_corner_angle(pl, dx, dz).ravel())
        offs.append(offs[-1] + (xl + 1) * (zl + 1))
    angles = jnp.concatenate(grids)
    zl_n = np.asarray([s[2] for s in rle.level_shapes], np.int64)[lev_n] + 1
    i00 = np.asarray(offs, np.int64)[lev_n] + ix_n.astype(np.int64) * zl_n + iz_n
    corner = jnp.stack([angles[i00 + d] for d in (0, 1, zl_n, zl_n + 1)])
    return _box_planes(rle, pl, corner, x0, z0, x0 + c, z0 + c, lev)


def _near_first(nx: int, nz: int, dx, dz):
    """(nx nz,) int32 the cells ``x * nz + z`` of an ``nx x nz`` grid, the eye's side first.

    Rows of cells across the axis the eye stands farther out along (``dx, dz``:
    the eye less the grid's centre), from the eye's side: near cells mostly come
    before far ones, with no sort.
    """
    p = jnp.arange(nx * nz, dtype=jnp.int32)
    by_x = jnp.where(dx > 0, nx * nz - 1 - p, p)
    pz = jnp.where(dz > 0, nx * nz - 1 - p, p)
    by_z = (pz % nx) * nz + pz // nx
    return jnp.where(jnp.abs(dz) > jnp.abs(dx), by_z, by_x)


def _draw_order(rle, cam: Camera, n: int):
    """(n,) int32 the flat elements in the order the windows draw them: near columns first.

    :func:`~.scatter._hidden` catches a pair only behind the writers of earlier windows.
    So the column heads come first, each level's in :func:`_near_first` order;
    then the tails (stored in column order), from the eye's side in x.  Which
    element wins a texel does not depend on it.
    """
    X, Z = rle.shape[0], rle.shape[2]
    dx = cam.position[0] - 0.5 * X
    dz = cam.position[2] - 0.5 * Z
    heads = [
        off + _near_first(xl, zl, dx, dz)
        for (xl, _, zl), off in zip(rle.level_shapes, rle.level_offsets)
    ]
    C = rle.count.shape[0]
    t = jnp.arange(n - C, dtype=jnp.int32)
    return jnp.concatenate([*heads, C + jnp.where(dx > 0, n - C - 1 - t, t)])
