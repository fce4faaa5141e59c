"""Rasterizing the ray buffer one cell per step: per-plane traversal, projection, culling, drawing.

The one-cell walk of thesis 4.5.4 (XLA:CPU's default; :mod:`.wide` walks a block of
cells per step).  Per plane, an exact 2-D DDA (Amanatides & Woo) walks the pointer
map from the eye outwards (4.5.4.1; jumping from an empty cell over the empty
square around it).  The loop has the design card's form: ``lax.scan`` over fixed
blocks of 4 steps with per-plane done masks inside (a done plane's step changes
nothing), and a ``lax.while_loop`` over the blocks that exits once every plane has
left the map, reached the far limit or closed its floating horizon: the step count
varies by orders of magnitude between planes and frames, so a fixed ``scan`` to the
worst case would walk every plane across the whole map.  Every RLE element of every
visited column is projected *once* into the plane's ray-buffer column (4.5.4.2,
Eq. 4.5) and culled by a floating horizon and a 1-bit coverage map (4.5.4.3).  The
drawn elements are appended front to back to the plane's list, so a texel's writer
is the first element covering its row (4.5.4.4; resolved for all texels by
:mod:`.texels`, for the texels the screen reads by
:func:`~jaxgfx.raycast.warp_lists`).

The frame's fixed cost follows the view, not the plane budget: a chunk of planes
draws into one chunk-sized list buffer, and only the elements drawn are copied into
the frame's pool.

Two tests that leave every drawn element as it is (not in the thesis): a plane
stops once its undrawn rows can no longer meet the scene's height range ``[0, top]``
past the walk's t (:func:`_live_rows`), and before each step a few cheap steps
(:func:`_free_step`, only a column's floor-to-top span projected) pass cells whose
whole column falls on rows already drawn.

A step reads its ``elements_per_step`` elements directly, their heights from the
running sums over the column's tail (:attr:`~jaxgfx.raycast.RLEVolume.tail_sums`,
computed once at encoding).  Values read by several fused ops are pinned with
:func:`_once` (XLA:CPU would recompute them in each).

Every mask op of a step is as wide as the column's coverage map.  With 2x1 AA a
column of the left and right segments has 2W rows, while the top and bottom
segments' columns have H: chunks of only those run a second loop program with maps
of ceil(H / 32) words (``short_rows``), when that saves :data:`_SPLIT_WORDS` words
(the second loop program is a second compile).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, camera_basis, focal_lengths
from jaxgfx._src.voxel.codec import ELEMENT_WORDS, NO_ENTRY, pack_drawn
from jaxgfx._src.voxel.grid import (
    _cell_height,
    _column_head,
    _column_runs,
    _element_bottoms,
    _level_tables,
    _map_column,
    _prefix_sum,
    _safe_div,
)
from jaxgfx._src.voxel.planes import Segments, plane_extent
from jaxgfx._src.voxel.walk import (
    _TINY,
    _cell_exit,
    _ChunkLoop,
    _free_step,
    _live_rows,
    _next_cell,
    _once,
    _PlaneConsts,
    _PlaneState,
    _row_mask,
    _rows_of,
    _scene_top,
    _slopes,
)

__all__ = ["traverse_lists"]

# Coverage words a chunk of short columns must save for the traversal to run two loop
# programs (one per coverage width): below this the second compile costs more than it
# saves (512x384 with 2x1 AA saves 20 of 32 words; 128x96 with 2x1 AA 5 of 8).
_SPLIT_WORDS = 16


# ---------------------------------------------------------------------------
# Helpers: front-to-back order
# ---------------------------------------------------------------------------


def _rank(j, n, m):
    """Front-to-back rank of element j within its column.

    Rays that hit elements below the eye descend (top element first); rays
    that hit elements above the eye ascend (bottom element first).  The two
    groups never compete for one ray, so one order serves both.
    """
    return jnp.where(j >= m, j - m, (n - m) + (m - 1 - j))


def _unrank(rank, n, m):
    return jnp.where(rank < n - m, m + rank, m - 1 - (rank - (n - m)))


# ---------------------------------------------------------------------------
# 4.5.4.1 - 4.5.4.3 Traversal per plane: one loop step
# ---------------------------------------------------------------------------


def _plane_init(rle, cam: Camera, seg: Segments, plane, *, rows: int, n_words: int):
    """Per-plane constants and the initial loop state (coverage of ``n_words`` words)."""
    # s_min / s_max: slopes visible in this plane, to clip element slopes to the screen.
    h, lo, hi, s_min, s_max = plane_extent(cam, seg, plane, rows=rows)
    s_idx = jnp.clip(jnp.searchsorted(seg.start + seg.count, plane, side="right"), 0, 3)
    vertical = s_idx < 2
    right, up, forward = camera_basis(cam)
    fx, fy = focal_lengths(cam)
    eye = cam.position
    ex, ez = eye[0], eye[2]
    hx, hz = h[0], h[1]
    inv_x = _safe_div(1.0, hx, 1e-12)
    inv_z = _safe_div(1.0, hz, 1e-12)
    # Eq. 4.5 in the plane: the ray-buffer coordinate of slope s is the
    # projective map (p + q s) / (g + d s) of the plane's camera-space terms.
    hr = right[0] * hx + right[2] * hz
    hu = up[0] * hx + up[2] * hz
    hf = forward[0] * hx + forward[2] * hz
    p_num = jnp.where(vertical, 0.5 * cam.height * hf - fy * hu, 0.5 * cam.width * hf + fx * hr)
    q_num = jnp.where(
        vertical,
        0.5 * cam.height * forward[1] - fy * up[1],
        0.5 * cam.width * forward[1] + fx * right[1],
    )
    # Entry into the map's x-z box (2-D slab test).
    X0, Z0 = float(rle.shape[0]), float(rle.shape[2])
    tx0, tx1 = (0.0 - ex) * inv_x, (X0 - ex) * inv_x
    tz0, tz1 = (0.0 - ez) * inv_z, (Z0 - ez) * inv_z
    t_enter = jnp.maximum(jnp.maximum(jnp.minimum(tx0, tx1), jnp.minimum(tz0, tz1)), 0.0)
    t_exit = jnp.minimum(jnp.maximum(tx0, tx1), jnp.maximum(tz0, tz1))
    t_far = jnp.minimum(t_exit, cam.far)
    p0x, p0z = ex + hx * t_enter, ez + hz * t_enter
    ix0 = jnp.clip(jnp.floor(p0x), 0, X0 - 1).astype(jnp.int32)
    iz0 = jnp.clip(jnp.floor(p0z), 0, Z0 - 1).astype(jnp.int32)
    done0 = (t_enter >= t_far) | (lo >= hi)
    carry0 = _PlaneState(
        ix=ix0,
        iz=iz0,
        lev=jnp.int32(0),
        t=t_enter,
        done=done0,
        lo=lo,
        hi=hi,
        cov=jnp.zeros((n_words,), jnp.uint32),
        first=jnp.full((n_words,), NO_ENTRY, jnp.int32),
        nbuf=jnp.int32(0),
        stats=jnp.zeros(3, jnp.int32),
        k=jnp.int32(0),
        it=jnp.int32(0),
    )
    consts = _PlaneConsts(hx, hz, inv_x, inv_z, t_far, s_min, s_max, hf, p_num, q_num)
    return consts, carry0


def _plane_step(
    rle,
    cam: Camera,
    consts: _PlaneConsts,
    carry: _PlaneState,
    *,
    lod_distance,
    K: int,
    n_words: int,
    Ec: int,
) -> tuple[_PlaneState, jax.Array, jax.Array]:
    """One loop step of one plane (see :func:`traverse_lists`); vmap over planes.

    Returns:
        ``(state, slots (Ec,), words (Ec, 5))``: the new state and the list slots
        (``K`` for none) and words of the elements drawn in this step.
    """
    t_far = consts.t_far
    L, off, sx, sy, sz = _level_tables(rle)
    E = rle.max_elements
    jE = jnp.arange(E)
    jC = jnp.arange(Ec)
    _, _, forward = camera_basis(cam)
    ey = cam.position[1]
    ix, iz, lev, t, done = carry.ix, carry.iz, carry.lev, carry.t, carry.done
    lo, hi, cov, nbuf = carry.lo, carry.hi, carry.cov, carry.nbuf
    stats, k, it = carry.stats, carry.k, carry.it
    c, t_out, go_x = _cell_exit(consts, cam, ix, iz, lev)
    in_map, has_tile, col = _map_column(rle, ix, iz, lev, off, sx, sz)
    inside = in_map & has_tile
    ok = inside & ~done
    safe, n, draw0, bottom0 = _column_head(rle, col, inside, sy[lev])
    # Elements above the eye come first in the column (top down).
    bottoms = _element_bottoms(rle, safe, bottom0, jE)[0]
    cy = _cell_height(rle, c)
    m = jnp.sum((jE < n) & (bottoms.astype(jnp.float32) * cy > ey)).astype(jnp.int32)
    # This step's Ec elements in front-to-back order (see _rank).
    rank = k + jC
    j = jnp.clip(_unrank(rank, n, m), 0, E - 1)
    top, bottom, valid, drawn_before = _column_runs(rle, safe, n, draw0, bottom0, j)
    y_lo = bottom.astype(jnp.float32) * cy
    y_hi = (top + 1).astype(jnp.float32) * cy
    valid = valid & (rank < n)
    t_in = jnp.maximum(t, _TINY)
    t_o = jnp.maximum(t_out, t_in)
    inv_in, inv_out = 1.0 / t_in, 1.0 / t_o
    # Eq. 4.5: project the element's corners (slopes dy/dt in the plane).
    e_smin, e_smax = _slopes(consts, y_lo, y_hi, ey, inv_in, inv_out)
    vis = valid & ok & (e_smin <= e_smax)
    # The rows of that slope range; the free step projects a column's span the same way.
    r0, r1 = _rows_of(consts, e_smin, e_smax, forward[1])
    # Floating horizon: rows outside [lo, hi) are already drawn.
    r0 = _once(jnp.maximum(r0, lo))
    r1 = _once(jnp.minimum(r1, hi))
    # Coverage culling (4.5.4.3): the thesis's 1-bit-per-pixel visibility
    # map of the column; an element that adds no new pixel is culled.
    cov_in = cov
    mask = _row_mask(r0, r1, n_words)  # (Ec, W) uint32
    fresh = jnp.any((mask & ~cov[None, :]) != 0, axis=1)
    draw = _once(vis & (r0 < r1) & fresh)  # read by six fused ops below
    drawn = jnp.where(draw[:, None], mask, jnp.uint32(0))
    cov = cov | jax.lax.reduce(drawn, np.uint32(0), jax.lax.bitwise_or, (0,))
    # Each coverage word's first list entry to draw in it (not in the thesis): a
    # row's writer, the first entry covering it, comes at or after it, so the warp's
    # search starts there, not at the list's head.
    pos = nbuf + _prefix_sum(draw.astype(jnp.int32)) - 1
    word_first = jnp.minimum(
        carry.first, jnp.min(jnp.where(drawn != 0, pos[:, None], NO_ENTRY), axis=0)
    )
    # The DDA moves on once the column's elements are all processed.
    advance = k + Ec >= n
    # Floating horizon: a bound that reaches drawn rows jumps over them.
    new_lo, new_hi = lo, hi
    for _ in range(2):
        new_lo = jnp.maximum(new_lo, jnp.max(jnp.where(draw & (r0 <= new_lo), r1, new_lo)))
        new_hi = jnp.minimum(new_hi, jnp.min(jnp.where(draw & (r1 >= new_hi), r0, new_hi)))
    # Done once every row between the bounds is drawn, or can no longer be:
    # a row whose ray has left the scene's height range for the rest of the
    # walk stays empty (not in the thesis).  Without this a plane looking
    # over an instance map walked to its far edge for the rows above the
    # horizon or between the crowns (1600 trees: every plane did).
    t_next = jnp.where(advance, t_o, t_in)
    a0, a1 = _live_rows(consts, ey, t_next, y_top=_scene_top(rle), fy=forward[1])
    open_rows = _row_mask(jnp.maximum(new_lo, a0)[None], jnp.minimum(new_hi, a1)[None], n_words)
    new_hi = jnp.where(jnp.any((open_rows[0] & ~cov) != 0), new_hi, new_lo)
    # Append drawn elements front to back: list order = visibility order.
    slot = jnp.where(draw & (pos < K), pos, K)
    cbase = rle.color_ptr[safe].astype(jnp.int32) + drawn_before
    bc = lambda v: jnp.broadcast_to(v, (Ec,))  # noqa: E731
    ivals = pack_drawn(r0, r1, top, bottom, cbase, bc(ix), bc(iz), bc(lev))
    n_draw = jnp.sum(draw).astype(jnp.int32)
    first = k == 0
    stats = stats + jnp.stack(
        [
            jnp.where(inside & first & ~done, n, 0),
            jnp.where(ok, jnp.clip(n - k, 0, Ec), 0),
            n_draw,
        ]
    ).astype(jnp.int32)
    ix_n, iz_n, lev_n, t_out, leaves = _next_cell(
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
        in_map & (n == 0) & (k == 0),
        lod_distance=lod_distance,
    )
    done_n = done | (advance & ((t_out >= t_far) | leaves)) | (new_lo >= new_hi)
    move = ~done & advance
    keep = lambda a, b: jnp.where(done, a, b)  # noqa: E731
    return (
        _PlaneState(
            ix=jnp.where(move, ix_n, ix),
            iz=jnp.where(move, iz_n, iz),
            lev=jnp.where(move, lev_n, lev),
            t=jnp.where(move, t_out, t),
            done=done_n,
            lo=keep(lo, new_lo),
            hi=keep(hi, new_hi),
            cov=jnp.where(done, cov_in, cov),
            first=word_first,
            nbuf=nbuf + n_draw,
            stats=stats,
            k=jnp.where(advance, 0, k + Ec),
            it=it + 1,
        ),
        slot,
        ivals,
    )


# ---------------------------------------------------------------------------
# 4.5.4 All planes
# ---------------------------------------------------------------------------


def traverse_lists(
    rle,
    cam: Camera,
    seg: Segments,
    planes: jax.Array,
    *,
    rows: int,
    max_steps: int,
    lod_distance: jax.Array,
    buffer_size: int | None = None,
    elements_per_step: int = 4,
    chunks: int = 32,
    block_steps: int = 4,
    pool_size: int | None = None,
    free_steps: int = 4,
    short_rows: int | None = None,
    with_steps: bool = False,
    consume=None,
    acc=None,
):
    """Renders a batch of planes into their ray-buffer columns (4.5.4).

    An exact 2-D DDA walks the pointer map from the eye outwards for at most
    ``max_steps`` cells (``lax.scan`` blocks of ``block_steps`` steps with a
    done mask, in a ``lax.while_loop`` so that a batch of planes stops as soon
    as all of them have left the map, reached the far limit or closed their
    floating horizon).  Each step works on up to
    ``elements_per_step`` elements of the current column, in front-to-back
    order, and moves to the next cell once the column is exhausted: the loop
    body is that narrow, while a column with many elements takes several
    steps.  From an empty cell the walk jumps to the first cell past the
    empty square that ``rle.empty_dist`` guarantees around it (or past an
    empty instance tile), stopping in the cell where the LOD band ends, so it
    visits exactly the non-empty cells of the plain DDA in fewer steps.  Each
    element of a visited column is projected once into the column (Eq. 4.5); elements left
    after floating-horizon culling are appended, front to back, to a list of
    drawn intervals; a texel's writer is the first element of the list that
    covers its row (:func:`traverse_planes` resolves them all,
    :func:`~jaxgfx.raycast.warp_lists` only those the screen's covered pixels
    read), so each ray-buffer pixel is drawn once.

    Args:
        rle: :class:`~jaxgfx.raycast.RLEVolume`.
        cam: camera.
        seg: frame's :class:`Segments`.
        planes: (P,) int32 plane indices.
        rows: static column length.
        max_steps: static bound on the 2-D DDA cells visited.
        lod_distance: () horizontal distance where mip level 1 starts; level
            ``l`` starts at ``lod_distance * 2 ** (l - 1)`` (``inf``: level 0 only).
        buffer_size: static number of drawn elements kept per plane (default
            ``max(64, rows // 2)``); the overflow (farthest elements) is counted
            in the last stat.
        elements_per_step: static number of a column's elements handled per
            loop step (default 4; any value gives the same image).
        block_steps: static; each ``while_loop`` iteration is a ``lax.scan`` of
            this many steps (default 4; 1: one step per iteration, no scan).  Any
            value gives the same frame (see the module docstring).
        chunks: static number of consecutive plane groups, each with its own
            loop (so it stops when its own planes are done); a group holding
            only planes past ``sum(seg.count)`` is skipped.
        pool_size: static number of drawn elements kept per frame, or per pass
            with ``consume`` (default ``P K``).
        free_steps: static; before each step, up to this many cheap steps pass
            cells that cannot draw (empty, or the whole column on drawn rows),
            while any plane of the chunk has one (default 4; 0: none).  Any
            value gives the same lists.
        short_rows: static; the most rows a plane of the top and bottom segments
            has (the camera height): chunks of only such planes run with coverage
            maps that long, when that saves at least ``_SPLIT_WORDS`` words
            (None: every chunk has ``rows``).  The same lists either way.
        with_steps: also return the dependent loop steps taken (every chunk's
            steps, free steps and copy steps, one after another).
        consume: None: one pass; the pool keeps ``pool_size`` elements and drops
            the rest (counted).  A function ``consume(lists, mine, acc) -> acc``:
            the frame is walked in passes, each filling the pool from its start
            with the next chunks until one does not fit (that one starts the next
            pass), then handing ``consume`` this function's return tuple and
            ``mine`` (P,) bool, the planes the pass walked (only their lists are
            in the pool).  The pool is a fresh buffer every frame, cleared before
            use; a small one that most frames fill once keeps the frame's memory
            (and on the CPU its page faults) small, and a frame that draws more
            takes more passes instead of a larger pool.
        acc: with ``consume``: its initial accumulator (a pytree).

    Returns:
        ``(pool (5, pool_size) int32, start (P,) int32, drawn (P,) int32, coverage
        (P, W) uint32, first (P, W) int32, stats (P, 4) int32)`` with ``W = ceil(rows /
        32)``: every plane's drawn elements front to back, back to back in the pool
        from ``start`` (row range, top / bottom voxel, colour index, cell x, z, level;
        :func:`~jaxgfx._src.voxel.codec.pack_drawn`), how many of them the pool kept,
        the column's 1-bit coverage map (rows drawn), the list entry that first drew
        in each coverage word (``NO_ENTRY`` for none; a row's writer comes at or
        after its word's), and the counts of elements in the visited columns,
        elements processed before the plane was done, elements drawn, drawn elements
        dropped by a full list or pool.  With ``consume``: ``(those, acc, passes)``,
        the last pass's tuple (its per-plane arrays hold every plane's values), the
        final accumulator and the number of passes () int32.
    """
    E = rle.max_elements
    K = max(64, rows // 2) if buffer_size is None else buffer_size
    K = -(-K // 8) * 8  # whole blocks of 8 (the copy into the pool)
    n_words = -(-rows // 32)
    if pool_size is None:
        pool_size = planes.shape[0] * K
    Ec = max(1, min(int(elements_per_step), E))
    # Every step either finishes a column (advancing the DDA) or works on Ec
    # more of its elements, so this bounds the loop.
    cap = max_steps * (-(-E // Ec))

    P = planes.shape[0]
    n_chunks = max(1, min(int(chunks), P))
    size = -(-P // n_chunks)
    Pp = n_chunks * size
    # Pad with an index past every budget so the padding planes are dead.
    padded = jnp.concatenate([planes, jnp.full((Pp - P,), 2**30, planes.dtype)])
    # Planes past the frame's plane count (the static budget covers vp on
    # screen; most views need fewer) come in whole chunks that are skipped.
    total = jnp.sum(seg.count)
    by_chunk = padded.reshape(n_chunks, size)
    live = jnp.any(by_chunk < total, axis=1)
    # Planes of the top and bottom segments (0, 1) are textured along screen y, so
    # their columns hold at most H rows: a chunk of only such planes runs with
    # coverage maps of ceil(H / 32) words instead of ceil(rows / 32).  Every mask
    # op of a step is that wide; with 2x1 AA (rows = 2W) most planes are such.
    n_short = -(-min(rows, short_rows or rows) // 32)
    groups = [(n_words, live)]  # below _SPLIT_WORDS: one loop program (one compile)
    if n_words - n_short >= _SPLIT_WORDS:
        short = jnp.all((by_chunk >= total) | (by_chunk < seg.start[2]), axis=1)
        groups = [(n_short, live & short), (n_words, live & ~short)]

    def chunk_fn(order, nw, stop):
        step = jax.vmap(
            lambda q, c: _plane_step(
                rle, cam, q, c, lod_distance=lod_distance, K=K, n_words=nw, Ec=Ec
            )
        )
        free = jax.vmap(
            lambda q, c: _free_step(rle, cam, q, c, lod_distance=lod_distance, n_words=nw)
        )
        return functools.partial(chunk, order, nw, step, free, stop)

    def chunk(order, nw, step, free, stop, i, w):
        # One loop per chunk, so it stops when its own planes are done.  Its
        # lists live in one chunk-sized buffer reused by every chunk (it stays
        # in cache), and only the elements drawn are copied into the frame's
        # pool: per-plane lists of K slots for the whole frame cost a fresh
        # P K-word buffer per frame, more than the traversal of a small scene.
        lists, pool, used, start, drawn, cov, word_first, stats, n_it, full, pass_of, pass_id = w
        base = order[i] * size
        part = jax.lax.dynamic_slice(padded, (base,), (size,))
        consts, carry0 = jax.vmap(lambda p: _plane_init(rle, cam, seg, p, rows=rows, n_words=nw))(
            part
        )
        dest = jnp.arange(size, dtype=jnp.int32)[:, None]

        def one(c, _=None):
            state, lists, n_free = c
            if free_steps > 0:
                # Its own loop: with the list buffer out of its carry.
                # While any plane of the chunk passes a cell, at most
                # free_steps times: the planes on cells that can draw wait.
                def pass_cells(f):
                    s, _, i = f
                    s, go = free(consts, s)
                    return s, jnp.any(go), i + 1

                state, _, taken = jax.lax.while_loop(
                    lambda f: f[1] & (f[2] < free_steps),
                    pass_cells,
                    (state, jnp.bool_(True), jnp.int32(0)),
                )
                n_free = n_free + taken
            state, slot, words = step(consts, state)
            return (state, lists.at[dest, :, slot].set(words, mode="drop"), n_free), None

        # The loop runs outside the vmap: its condition is "any plane still
        # going", so the per-plane done masks do the work.
        def going(c):
            return jnp.any(~c[0].done) & (c[0].it[0] < cap)

        if block_steps <= 1:
            body = lambda c: one(c)[0]  # noqa: E731
        else:
            # The design card's form: lax.scan over fixed blocks of steps (a
            # done plane's step changes nothing), the early exit between blocks.
            body = lambda c: jax.lax.scan(one, c, None, block_steps)[0]  # noqa: E731
        state, lists, n_free = jax.lax.while_loop(going, body, (carry0, lists, jnp.int32(0)))
        nbuf = state.nbuf
        # The chunk's lists, back to back from the pool's first free slot.
        kept = jnp.minimum(nbuf, K)
        first = used + _prefix_sum(kept) - kept
        room = pool.shape[1]
        stored = jnp.clip(room - first, 0, kept)
        # stop: a chunk whose lists do not all fit is not committed (the pool's
        # fill stays and its planes are not marked; the next pass walks it
        # again) and the pass ends.  An empty pool takes any chunk (what it
        # cannot hold is dropped and counted), so every pass moves on.
        fits = ((used + jnp.sum(kept) <= room) | (used == 0)) if stop else jnp.bool_(True)

        # Copied 8 slots per plane at a time up to the chunk's longest list
        # (most are short); a loop, as a cond would copy the whole pool.
        def copy(b, pool):
            j = b * 8 + jnp.arange(8, dtype=jnp.int32)[None, :]
            slots = jnp.where(j < stored[:, None], first[:, None] + j, pool_size)
            part = jax.lax.dynamic_slice_in_dim(lists, jnp.minimum(b * 8, K - 8), 8, axis=2)
            return pool.at[:, slots].set(jnp.moveaxis(part, 1, 0), mode="drop")

        pool = jax.lax.fori_loop(0, (jnp.max(stored) + 7) // 8, copy, pool)
        lost = jnp.maximum(nbuf - stored, 0)
        st = jnp.concatenate([state.stats, lost[:, None]], axis=1)
        put = lambda buf, v: jax.lax.dynamic_update_slice_in_dim(buf, v, base, 0)  # noqa: E731
        return _ChunkLoop(
            lists,
            pool,
            used + jnp.where(fits, jnp.sum(stored), 0),
            put(start, first),
            put(drawn, stored),
            put(cov, jnp.pad(state.cov, ((0, 0), (0, n_words - nw)))),
            put(
                word_first,
                jnp.pad(state.first, ((0, 0), (0, n_words - nw)), constant_values=NO_ENTRY),
            ),
            put(stats, st),
            # Dependent loop steps: the chunk's steps, its free steps and its copy steps.
            n_it + state.it[0] + n_free + (jnp.max(stored) + 7) // 8,
            full | ~fits,
            put(pass_of, jnp.full((size,), jnp.where(fits, pass_id, -1), jnp.int32)),
            pass_id,
        )

    plan = [
        (nw, jnp.nonzero(mine, size=n_chunks, fill_value=0)[0], jnp.sum(mine.astype(jnp.int32)))
        for nw, mine in groups
    ]

    def run(w: _ChunkLoop, starts, stop: bool):
        # Each group's chunks from starts[g]; with stop, until a chunk does not fit.
        ends = []
        for g, (nw, order, n) in enumerate(plan):
            body = chunk_fn(order, nw, stop)

            def one_chunk(c, body=body):
                new = body(c[0], c[1])
                return jnp.where(new.full, c[0], c[0] + 1), new

            going = lambda c, n=n: (c[0] < n) & ~c[1].full  # noqa: E731
            i, w = jax.lax.while_loop(going, one_chunk, (starts[g], w))
            ends.append(i)
        return w, ends

    def result(w: _ChunkLoop):
        per_plane = (w.start, w.drawn, w.cov, w.first, w.stats)
        out = (w.pool,) + (per_plane if Pp == P else tuple(o[:P] for o in per_plane))
        return out + (w.steps,) if with_steps else out

    w0 = _ChunkLoop(
        jnp.zeros((size, ELEMENT_WORDS, K), jnp.int32),
        jnp.zeros((ELEMENT_WORDS, pool_size), jnp.int32),
        jnp.int32(0),
        jnp.zeros((Pp,), jnp.int32),
        jnp.zeros((Pp,), jnp.int32),
        jnp.zeros((Pp, n_words), jnp.uint32),
        jnp.full((Pp, n_words), NO_ENTRY, jnp.int32),
        jnp.zeros((Pp, 4), jnp.int32),
        jnp.int32(0),
        jnp.bool_(False),
        jnp.full((Pp,), -1, jnp.int32),
        jnp.int32(0),
    )
    starts0 = [jnp.int32(0)] * len(plan)
    if consume is None:
        return result(run(w0, starts0, False)[0])

    # Passes: each fills the pool from its first element with the next chunks
    # until one does not fit, and hands the lists of the planes it walked to
    # consume; the pool is reused (its contents never cleared again).
    def unfinished(c):
        return jnp.any(jnp.stack([c[0][g] < n for g, (_, _, n) in enumerate(plan)]))

    def one_pass(c):
        starts, w, acc = c
        w = w._replace(used=jnp.int32(0), full=jnp.bool_(False), pass_id=w.pass_id + 1)
        w, ends = run(w, starts, True)
        mine = w.pass_of == w.pass_id
        acc = consume(result(w), mine if Pp == P else mine[:P], acc)
        return ends, w, acc

    # A frame without live chunks takes no pass: acc stays as given.
    _, w, acc = jax.lax.while_loop(unfinished, one_pass, (starts0, w0, acc))
    return result(w), acc, w.pass_id
