"""The per-plane traversal in wide steps: a block of cells per plane per loop step (thesis 4.5.4).

:func:`traverse_wide` draws the ray buffer as lists: every plane's drawn RLE
elements, front to back, with the planes' 1-bit coverage maps, which the warp
(:func:`~jaxgfx._src.voxel.warp.warp_lists`) reads.  It is the renderer's walk for a
map beyond the scatter's limits
(:func:`~jaxgfx._src.voxel.scatter.scatter_limits`).  Where the thesis walks one
cell per plane per step, one loop step moves every plane of the frame over a
*block*: up to ``block_cells`` cells of its line along the major axis of its x-z
direction, at one mip level.  The exact 2-D DDA's cells for that stretch have a
closed form: a line whose slope is at most one crosses one or two cells per
major-axis column (the second where it crosses the minor axis), so the block's
cells are the entry and exit cells of consecutive columns.  The block ends where the
column's LOD band ends (4.5.4.1: mip level ``l`` from ``lod_distance 2^(l-1)``),
where the map or the far limit ends, or before the column whose elements would pass
``block_elements``; the elements of its cells are packed into ``block_elements``
slots in walk order (cell by cell, each column's elements front to back), projected
to ray-buffer rows (Eq. 4.5) and culled against the floating horizon and the
coverage map as they stood before the step (4.5.4.3).  An element hidden only by
another element of the same block is therefore drawn as well; it comes after its
occluder in the list, so the warp, which takes a row's first covering entry, shows
the same texel.  After the step the coverage map takes the block's drawn rows and
the floating horizon jumps over every drawn row at its ends.

The number of loop steps per frame is the number of blocks of the plane that
needs the most, so a frame takes tens of steps, each as wide as all planes of
the frame times a block.  Under ``vmap`` the planes of all cameras form one
wider array: a batch takes about as many steps as its slowest frame.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, camera_basis
from jaxgfx._src.compaction import short_running_sum
from jaxgfx._src.voxel.codec import ELEMENT_WORDS, NO_ENTRY, pack_drawn
from jaxgfx._src.voxel.grid import (
    _cell_height,
    _column_head,
    _column_runs,
    _level_tables,
    _map_column,
)
from jaxgfx._src.voxel.planes import Segments
from jaxgfx._src.voxel.walk import (
    _TINY,
    _live_rows,
    _once,
    _plane_init,
    _PlaneConsts,
    _row_mask,
    _rows_of,
    _scene_top,
    _slopes,
    _unrank,
)

__all__ = ["traverse_wide", "default_block_elements"]


def default_block_elements(max_elements: int, block_cells: int) -> int:
    """Element slots per plane per step: at least two whole columns (:func:`traverse_wide`)."""
    return int(max(2 * max_elements, 2 * block_cells, 8))


class _WideState(NamedTuple):
    """Loop state of one plane in :func:`traverse_wide` (vmap adds the plane axis)."""

    m: jax.Array  # () int32, next major-axis cell index at level ``lev``
    lev: jax.Array  # () int32, mip level of the walk
    t: jax.Array  # () float32, horizontal distance the walk has reached
    done: jax.Array  # () bool
    lo: jax.Array  # () int32, floating horizon: first row not yet drawn
    hi: jax.Array  # () int32, floating horizon: one past the last row not yet drawn
    cov: jax.Array  # (W,) uint32, 1-bit coverage map of the column
    first: jax.Array  # (W,) int32, list entry that first drew in each coverage word
    nbuf: jax.Array  # () int32, elements drawn so far
    stats: jax.Array  # (3,) int32, elements in visited columns / processed / drawn


def _once_f(x):
    """Float ``x`` computed once for all of its users (as :func:`~.walk._once` for ints)."""
    return jnp.min(jnp.stack([x, jnp.full_like(x, jnp.inf)], axis=-1), axis=-1)


def _cummax(x):
    """Inclusive running maximum along the last (short, static) axis by log-step shifts."""
    n = x.shape[-1]
    k = 1
    while k < n:
        pad = jnp.full(x.shape[:-1] + (k,), jnp.iinfo(x.dtype).min, x.dtype)
        x = jnp.maximum(x, jnp.concatenate([pad, x[..., : n - k]], axis=-1))
        k *= 2
    return x


def _prefix_or(x):
    """Inclusive running bitwise or along the first (short, static) axis by log-step shifts."""
    n = x.shape[0]
    k = 1
    while k < n:
        x = x | jnp.concatenate([jnp.zeros_like(x[:k]), x[: n - k]], axis=0)
        k *= 2
    return x


def _open_bounds(cov, lo, hi, n_words):
    """First and one-past-last row of ``[lo, hi)`` not yet covered: the floating horizon.

    Returns ``(lo', hi')`` with ``lo' >= hi'`` when every row between them is drawn.
    """
    span = _row_mask(lo[None], hi[None], n_words)[0]
    open_ = span & ~cov
    any_w = open_ != 0
    idx = jnp.arange(n_words, dtype=jnp.int32)
    w0 = jnp.min(jnp.where(any_w, idx, n_words))
    w1 = jnp.max(jnp.where(any_w, idx, -1))
    v0 = open_[jnp.clip(w0, 0, n_words - 1)]
    v1 = open_[jnp.clip(w1, 0, n_words - 1)]
    low_bit = 31 - jax.lax.clz(v0 & (~v0 + jnp.uint32(1))).astype(jnp.int32)
    high_bit = 31 - jax.lax.clz(v1).astype(jnp.int32)
    none = w0 >= n_words
    return jnp.where(none, hi, 32 * w0 + low_bit), jnp.where(none, hi, 32 * w1 + high_bit + 1)


def _columns_above(rle, ey, steps: int):
    """Per pointer-map entry (C,): the column's elements whose bottom lies above the eye.

    Element bottoms fall with the element index, so the count is where the test
    ``bottom 2^l > ey`` flips: a bisection of ``steps = ceil(log2(E + 1))`` reads per
    column, once per frame, instead of per visited cell and step.
    """
    C = rle.count.shape[0]
    offs = np.asarray(rle.level_offsets, np.int64)
    lev = jnp.asarray(np.searchsorted(offs, np.arange(C), side="right") - 1, jnp.int32)
    sy = jnp.asarray(np.asarray([sh[1] for sh in rle.level_shapes], np.int32))
    safe, n, _, bottom0 = _column_head(rle, jnp.arange(C), jnp.ones((C,), bool), sy[lev])
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    base = rle.ptr[safe].astype(jnp.int32) - 1
    last = rle.elements.shape[0] - 1
    lo = jnp.zeros((C,), jnp.int32)
    hi = n
    for _ in range(steps):
        mid = (lo + hi) // 2
        below = rle.tail_sums[0, jnp.clip(base + mid, 0, last)].astype(jnp.int32)
        b = jnp.where(mid == 0, bottom0, bottom0 - below)
        above = (b.astype(jnp.float32) * _cell_height(rle, c) > ey) & (mid < hi)
        lo = jnp.where(above, mid + 1, lo)
        hi = jnp.where(above, hi, mid)
    return lo


def _block_cells(rle, cam: Camera, consts: _PlaneConsts, state: _WideState, lod, *, K: int):
    """The next block's cells of one plane in walk order: the 2-D DDA in closed form.

    Returns per cell (2K,) arrays ``(ix, iz, t_in, t_out, ok)`` and per column (K,)
    arrays ``(t_out, ok)`` at the block's level ``lev``, with the new ``m`` and
    ``lev`` (the level the band of ``state.t`` asks for).
    """
    L, _, sx, _, sz = _level_tables(rle)
    ex, ez = cam.position[0], cam.position[2]
    hx, hz = consts.hx, consts.hz
    xmajor = jnp.abs(hx) >= jnp.abs(hz)
    t = state.t
    # The level of this block: the band the walk is in (4.5.4.1), never finer.
    ratio = jnp.where(jnp.isfinite(lod), t / jnp.maximum(lod, _TINY), 0.0)
    want = jnp.where(
        ratio >= 1.0, jnp.floor(jnp.log2(jnp.maximum(ratio, 1.0))).astype(jnp.int32) + 1, 0
    )
    lev = jnp.clip(jnp.maximum(want, state.lev), 0, L - 1)
    m = state.m >> (lev - state.lev)
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    band = jnp.where(lev < L - 1, lod * c, jnp.inf)
    e_a, e_b = jnp.where(xmajor, ex, ez), jnp.where(xmajor, ez, ex)
    h_a, h_b = jnp.where(xmajor, hx, hz), jnp.where(xmajor, hz, hx)
    inv_a = jnp.where(xmajor, consts.inv_x, consts.inv_z)
    inv_b = jnp.where(xmajor, consts.inv_z, consts.inv_x)
    tx, tz = rle.tiles.shape
    size_a = jnp.where(xmajor, tx * sx[lev], tz * sz[lev])
    size_b = jnp.where(xmajor, tz * sz[lev], tx * sx[lev])
    s_a = jnp.where(h_a > 0, 1, -1).astype(jnp.int32)
    k = jnp.arange(K, dtype=jnp.int32)
    mk = m + s_a * k
    near = (mk + (s_a < 0).astype(jnp.int32)).astype(jnp.float32) * c
    far = (mk + (s_a > 0).astype(jnp.int32)).astype(jnp.float32) * c
    t_near = (near - e_a) * inv_a
    t_in = jnp.maximum(t_near, t)
    t_out = jnp.minimum((far - e_a) * inv_a, consts.t_far)
    # A column the walk only touches (the eye on its far face) stays in the walk.
    col_ok = (t_in < consts.t_far) & (mk >= 0) & (mk < size_a) & ((k == 0) | (t_near < band))
    col_ok = jnp.cumsum(col_ok.astype(jnp.int32)) == k + 1  # a prefix of the columns
    # Minor-axis cells at the column's entry and exit: one cell, or two when the
    # line crosses a minor-axis face inside the column (|h_b| <= |h_a|).
    j_in = jnp.floor((e_b + h_b * t_in) / c).astype(jnp.int32)
    j_out = jnp.floor((e_b + h_b * t_out) / c).astype(jnp.int32)
    j_out = jnp.clip(j_out, j_in - 1, j_in + 1)
    two = j_out != j_in
    t_x = ((jnp.maximum(j_in, j_out)).astype(jnp.float32) * c - e_b) * inv_b
    t_x = jnp.where(two, jnp.clip(t_x, t_in, t_out), t_out)
    j = jnp.stack([j_in, j_out], axis=1).reshape(-1)
    ma = jnp.repeat(mk, 2)
    c_in = jnp.stack([t_in, t_x], axis=1).reshape(-1)
    c_out = jnp.stack([t_x, t_out], axis=1).reshape(-1)
    c_ok = jnp.stack([col_ok, col_ok & two], axis=1).reshape(-1) & (j >= 0) & (j < size_b)
    ix = jnp.where(xmajor, ma, j)
    iz = jnp.where(xmajor, j, ma)
    return (ix, iz, c_in, c_out, c_ok), (t_out, col_ok), m, lev, s_a, size_a


def _wide_step(
    rle,
    cam: Camera,
    consts: _PlaneConsts,
    state: _WideState,
    lod,
    *,
    K: int,
    M: int,
    n_words: int,
    above: jax.Array,
):
    """One loop step of one plane: a block of cells (see :func:`traverse_wide`); vmap over planes.

    Returns:
        ``(state, slots (M,), words (M, 5))``: the new state, the list slots
        (``NO_ENTRY`` for none) and words of the elements drawn in this step.
    """
    _, off, sx, sy, sz = _level_tables(rle)
    _, _, forward = camera_basis(cam)
    ey = cam.position[1]
    done, lo, hi, cov = state.done, state.lo, state.hi, state.cov
    (ix, iz, t_in, t_out, c_ok), (col_t_out, col_ok), m, lev, s_a, size_a = _block_cells(
        rle, cam, consts, state, lod, K=K
    )
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    # Pinned (see _once): XLA:CPU would recompute them in every fused consumer.
    ix, iz = _once(ix), _once(iz)
    t_in, t_out = _once_f(t_in), _once_f(t_out)
    in_map, has_tile, col = _map_column(rle, ix, iz, lev, off, sx, sz)
    inside = in_map & has_tile & c_ok
    safe, n, draw0, bottom0 = (_once(v) for v in _column_head(rle, col, inside, sy[lev]))
    # Whole columns, as many as fit the step's element slots (M >= two columns).
    per_col = n.reshape(K, 2).sum(axis=1)
    fits = short_running_sum(per_col) <= M
    take = col_ok & fits
    kk = jnp.sum(take.astype(jnp.int32))
    n = jnp.where(jnp.repeat(take, 2), n, 0)
    cum = short_running_sum(n)
    start = cum - n
    total = cum[-1]
    # Element slot -> cell: each non-empty cell marks its first slot, a running max fills.
    cells = jnp.arange(2 * K, dtype=jnp.int32)
    mark = jnp.full((M,), -1, jnp.int32).at[jnp.where(n > 0, start, M)].max(cells, mode="drop")
    cell = _once(jnp.clip(_cummax(mark), 0, 2 * K - 1))
    slot = jnp.arange(M, dtype=jnp.int32)
    g = lambda a: a[cell]  # noqa: E731
    nc = g(n)
    e_safe = _once(g(safe))
    # Front-to-back rank within the cell's column, as the thesis's walk orders it.
    rank = slot - g(start)
    jj = _once(jnp.clip(_unrank(rank, nc, above[e_safe]), 0, rle.max_elements - 1))
    top, bottom, valid, drawn_before = (
        _once(v) for v in _column_runs(rle, e_safe, nc, g(draw0), g(bottom0), jj)
    )
    valid = valid & (slot < total) & ~done
    cy = _cell_height(rle, c)
    y_lo = bottom.astype(jnp.float32) * cy
    y_hi = (top + 1).astype(jnp.float32) * cy
    e_in = _once_f(jnp.maximum(g(t_in), _TINY))
    e_out = _once_f(jnp.maximum(g(t_out), e_in))
    e_smin, e_smax = _slopes(consts, y_lo, y_hi, ey, 1.0 / e_in, 1.0 / e_out)
    r0, r1 = _rows_of(consts, e_smin, e_smax, forward[1])
    r0 = _once(jnp.maximum(r0, lo))
    r1 = _once(jnp.minimum(r1, hi))
    vis = valid & (e_smin <= e_smax) & (r0 < r1)
    # Coverage culling (4.5.4.3) in walk order within the block: the rows drawn
    # before an element are the map before the step and every earlier element's
    # rows (an element that drew nothing adds no row, so the prefix may take all).
    vis = _once(vis)
    mask = _once(jnp.where(vis[:, None], _row_mask(r0, r1, n_words), jnp.uint32(0)))
    before = _prefix_or(mask)
    before = jnp.concatenate([jnp.zeros_like(before[:1]), before[:-1]], axis=0)
    fresh = jnp.any((mask & ~(cov[None, :] | before)) != 0, axis=1)
    draw = _once(vis & fresh)
    drawn = jnp.where(draw[:, None], mask, jnp.uint32(0))
    cov_n = cov | before[-1] | mask[-1]
    pos = state.nbuf + short_running_sum(draw.astype(jnp.int32)) - 1
    first = jnp.minimum(state.first, jnp.min(jnp.where(drawn != 0, pos[:, None], NO_ENTRY), axis=0))
    cbase = rle.color_ptr[e_safe].astype(jnp.int32) + drawn_before
    words = pack_drawn(r0, r1, top, bottom, cbase, g(ix), g(iz), jnp.broadcast_to(lev, (M,)))
    slots = jnp.where(draw, pos, NO_ENTRY)
    n_draw = jnp.sum(draw.astype(jnp.int32))
    # The walk moves past the block's columns; the floating horizon jumps over
    # every drawn row at its ends and over rows that can no longer meet the scene.
    last = jnp.clip(kk - 1, 0, K - 1)
    t_next = jnp.where(kk > 0, col_t_out[last], state.t)
    m_next = m + s_a * kk
    a0, a1 = _live_rows(consts, ey, t_next, y_top=_scene_top(rle), fy=forward[1])
    new_lo, new_hi = _open_bounds(cov_n, jnp.maximum(lo, a0), jnp.minimum(hi, a1), n_words)
    ended = (kk == 0) | (t_next >= consts.t_far) | (m_next < 0) | (m_next >= size_a)
    done_n = done | ended | (new_lo >= new_hi)
    stats = state.stats + jnp.stack(
        [jnp.where(done, 0, total), jnp.sum(valid.astype(jnp.int32)), n_draw]
    ).astype(jnp.int32)
    keep = lambda a, b: jnp.where(done, a, b)  # noqa: E731
    new = _WideState(
        m=keep(state.m, m_next),
        lev=keep(state.lev, lev),
        t=keep(state.t, t_next),
        done=done_n,
        lo=keep(lo, new_lo),
        hi=keep(hi, new_hi),
        cov=keep(cov, cov_n),
        first=keep(state.first, first),
        nbuf=state.nbuf + n_draw,
        stats=stats,
    )
    return new, slots, words


def traverse_wide(
    rle,
    cam: Camera,
    seg: Segments,
    planes: jax.Array,
    *,
    rows: int,
    lod_distance: jax.Array,
    buffer_size: int | None = None,
    block_cells: int = 32,
    block_elements: int | None = None,
    max_iterations: int | None = None,
    slots: int | None = None,
):
    """Renders all planes into ray-buffer lists in wide steps (4.5.4; see the module docstring).

    Args:
        rle: :class:`~jaxgfx.raycast.RLEVolume`.
        cam: camera.
        seg: the frame's :class:`Segments`.
        planes: (P,) int32 plane indices (those past ``sum(seg.count)`` stay empty).
        rows: static column length.
        lod_distance: () horizontal distance where mip level 1 starts.
        buffer_size: static drawn elements kept per plane (default ``max(64, rows // 2)``);
            the overflow (farthest elements) is counted in the last stat.
        block_cells: static major-axis columns per block (up to two cells each).
        block_elements: static element slots per plane per step (default
            :func:`default_block_elements`); a block ends before the column that
            would pass them.
        max_iterations: static bound on the loop steps (default: one per level-0
            column a plane can cross, times the rounds of slots).
        slots: static; None: every plane steps in every loop step (a done
            plane's step is idle work).  An int: that many planes step at a time,
            a done plane's slot taking the next live plane (more loop steps, each
            narrower; the same lists).

    Returns:
        ``(pool (5, P K) int32, start (P,), drawn (P,), coverage (P, W) uint32,
        first (P, W) int32, stats (P, 4) int32, iterations () int32)`` with ``W =
        ceil(rows / 32)``: every plane's drawn elements front to back, plane ``p``'s
        from ``p K`` in the pool (row range, top / bottom voxel, colour index, cell
        x, z, level; :func:`~jaxgfx._src.voxel.codec.pack_drawn`), how many of them
        it kept, the column's 1-bit coverage map (rows drawn), the list entry that
        first drew in each coverage word (``NO_ENTRY`` for none; a row's writer
        comes at or after its word's), the counts of elements in the visited
        columns, elements processed before the plane was done, elements drawn and
        drawn elements dropped by a full list; and the loop steps taken.
    """
    E = rle.max_elements
    K = int(block_cells)
    M = default_block_elements(E, K) if block_elements is None else int(block_elements)
    if M < 2 * E:
        raise ValueError(f"block_elements must hold two columns of {E} elements, got {M}")
    Kb = max(64, rows // 2) if buffer_size is None else int(buffer_size)
    n_words = -(-rows // 32)
    P = planes.shape[0]
    search_steps = max(1, int(np.ceil(np.log2(E + 1))))
    if max_iterations is None:
        # Every step moves a live plane over at least one column (M holds two).
        max_iterations = rle.shape[0] + rle.shape[2] + 2 + rle.levels
    consts, c0 = jax.vmap(lambda p: _plane_init(rle, cam, seg, p, rows=rows, n_words=n_words))(
        planes
    )
    xmajor = jnp.abs(consts.hx) >= jnp.abs(consts.hz)
    state0 = _WideState(
        m=jnp.where(xmajor, c0.ix, c0.iz),
        lev=c0.lev,
        t=c0.t,
        done=c0.done,
        lo=c0.lo,
        hi=c0.hi,
        cov=c0.cov,
        first=c0.first,
        nbuf=c0.nbuf,
        stats=c0.stats,
    )
    lod = jnp.asarray(lod_distance, jnp.float32)
    above = _columns_above(rle, cam.position[1], search_steps)
    step = jax.vmap(
        lambda q, s: _wide_step(rle, cam, q, s, lod, K=K, M=M, n_words=n_words, above=above)
    )
    lists0 = jnp.zeros((ELEMENT_WORDS, P, Kb), jnp.int32)
    if slots is None or slots >= P:
        state, lists, it = _walk_all(step, consts, state0, lists0, Kb, max_iterations)
    else:
        max_iterations = max_iterations * -(-P // slots)
        state, lists, it = _walk_slots(step, consts, state0, lists0, Kb, slots, max_iterations)
    drawn = jnp.minimum(state.nbuf, Kb)
    lost = jnp.maximum(state.nbuf - Kb, 0)
    stats = jnp.concatenate([state.stats, lost[:, None]], axis=1)
    start = jnp.arange(P, dtype=jnp.int32) * Kb
    return lists.reshape(ELEMENT_WORDS, P * Kb), start, drawn, state.cov, state.first, stats, it


def _append(lists, pid, slots, words, Kb):
    """Writes drawn elements' words at their list slots of plane ``pid`` (past ``Kb``: dropped)."""
    slots = jnp.where(slots < Kb, slots, Kb)
    return lists.at[:, pid[:, None], slots].set(jnp.moveaxis(words, -1, 0), mode="drop")


def _walk_all(step, consts, state0, lists0, Kb, max_iterations):
    """Every plane steps in every iteration until all are done (a done plane's step is idle)."""
    pid = jnp.arange(state0.done.shape[0], dtype=jnp.int32)

    def body(carry):
        state, lists, it = carry
        state, slots, words = step(consts, state)
        return state, _append(lists, pid, slots, words, Kb), it + 1

    def going(carry):
        return jnp.any(~carry[0].done) & (carry[2] < max_iterations)

    return jax.lax.while_loop(going, body, (state0, lists0, jnp.int32(0)))


def _walk_slots(step, consts, state0, lists0, Kb, S, max_iterations):
    """``S`` slots step; a slot whose plane is done takes the next plane not yet started.

    Planes that start done (past the frame's count, no rows) are never queued.  A
    finished plane's state is written back to its row of the per-plane state, so
    the result is the one of :func:`_walk_all`, with every step as wide as the
    slots instead of the plane budget.
    """
    P = state0.done.shape[0]
    queue = jnp.nonzero(~state0.done, size=P, fill_value=P)[0].astype(jnp.int32)
    n_live = jnp.sum((~state0.done).astype(jnp.int32))
    take = lambda tree, i: jax.tree_util.tree_map(lambda a: a[jnp.minimum(i, P - 1)], tree)  # noqa: E731

    def load(i):
        st = take(state0, i)
        return st._replace(done=st.done | (i >= P))

    pid0 = queue[:S]
    carry0 = (load(pid0), pid0, jnp.minimum(n_live, S), state0, lists0, jnp.int32(0))

    def body(carry):
        state, pid, nxt, out, lists, it = carry
        state, slots, words = step(take(consts, pid), state)
        lists = _append(lists, pid, slots, words, Kb)
        # Finished planes go back to their rows; their slots take queued planes.
        fin = state.done
        dest = jnp.where(fin & (pid < P), pid, P)
        out = jax.tree_util.tree_map(lambda o, v: o.at[dest].set(v, mode="drop"), out, state)
        rank = short_running_sum(fin.astype(jnp.int32)) - 1
        q = nxt + rank
        new = jnp.where(q < n_live, queue[jnp.minimum(q, P - 1)], P)
        new = jnp.where(fin, new, pid)
        fresh = load(new)
        state = jax.tree_util.tree_map(
            lambda a, b: jnp.where(fin.reshape(fin.shape + (1,) * (a.ndim - 1)), b, a),
            state,
            fresh,
        )
        nxt = jnp.minimum(nxt + jnp.sum(fin.astype(jnp.int32)), n_live)
        return state, new, nxt, out, lists, it + 1

    def going(carry):
        return jnp.any(~carry[0].done) & (carry[5] < max_iterations)

    _, _, _, out, lists, it = jax.lax.while_loop(going, body, carry0)
    return out, lists, it
