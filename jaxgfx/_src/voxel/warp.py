"""Displaying the ray buffer (thesis 4.5.5, Eq. 4.6) and the exact per-pixel re-walk.

Every screen pixel finds its ray-buffer texel (:func:`ray_buffer_coords`) and
intersects its own ray with that texel's drawn element, and with those of the
adjacent planes (:func:`_nearest_candidate`): from the wide traversal's lists
(:func:`warp_lists`) or from the scatter's texels
(:func:`~jaxgfx._src.voxel.scatter_warp.warp_texels`).  Pixels whose ray entered
none of them re-walk a few voxels of their own ray through the RLE columns
(:func:`refine_hits`, not in the thesis).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxgfx._src.camera import Camera, camera_basis, pixel_rays, screen_to_camera
from jaxgfx._src.voxel.codec import (
    NO_ENTRY,
    WORD_COLOR,
    WORD_HEIGHTS,
    WORD_ROWS,
    WORD_X,
    WORD_Z_LEVEL,
    unpack_drawn_box,
    unpack_drawn_rows,
)
from jaxgfx._src.voxel.grid import (
    _cell_height,
    _column_elements,
    _dda_entry,
    _level_tables,
    _map_column,
    _safe_div,
)
from jaxgfx._src.voxel.planes import Segments, _sgn_w

__all__ = [
    "ray_buffer_coords",
    "warp_lists",
    "refine_pixel",
    "refine_hits",
]

# ---------------------------------------------------------------------------
# 4.5.5 Ray buffer -> screen (Eq. 4.6)
# ---------------------------------------------------------------------------


def _ray_buffer_texel(cam: Camera, seg: Segments):
    """Per pixel: segment start, plane index in the segment, its count, row, ok."""
    px = jnp.arange(cam.width, dtype=jnp.float32)[None, :] + 0.5
    py = jnp.arange(cam.height, dtype=jnp.float32)[:, None] + 0.5
    return _texel_at(cam, seg, px, py)


def _texel_at(cam: Camera, seg: Segments, px, py):
    """:func:`_ray_buffer_texel` at pixel centres ``(px, py)`` (broadcast arrays)."""
    W, H = cam.width, cam.height
    vp_h = seg.vp_h
    w = vp_h[2]
    sw = _sgn_w(w)
    dx = vp_h[0] - px * w
    dy = vp_h[1] - py * w
    vert = jnp.abs(dy) >= jnp.abs(dx)
    s = jnp.where(vert, jnp.where(dy * sw > 0, 0, 1), jnp.where(dx * sw > 0, 2, 3))
    da = jnp.where(vert, dy, dx)
    db = jnp.where(vert, dx, dy)
    pa = jnp.where(vert, py, px)
    pb = jnp.where(vert, px, py)
    a_ref = jnp.stack([-float(H), 2.0 * H, -float(W), 2.0 * W])[s]
    u = pb + (a_ref - pa) * _safe_div(db, da)
    lo, hi, cnt, st = seg.u_lo[s], seg.u_hi[s], seg.count[s], seg.start[s]
    x = (u - lo) / jnp.maximum(hi - lo, 1e-12) * cnt.astype(jnp.float32) - seg.phase
    i = jnp.clip(jnp.floor(x + 0.5).astype(jnp.int32), 0, jnp.maximum(cnt - 1, 0))
    row = jnp.floor(pa).astype(jnp.int32)
    # Planes may cover only the scene's screen rectangle (screen_segments):
    # pixels more than a plane beyond the outermost ones see nothing.
    inside = (x > -1.5) & (x < cnt.astype(jnp.float32) + 0.5)
    return st, i, cnt, row, (cnt > 0) & inside


def ray_buffer_coords(cam: Camera, seg: Segments):
    """Ray-buffer texel ``(plane, row)`` of every screen pixel (Eq. 4.6, Fig. 4.14).

    For segments 0/1 the row is the pixel's y and the plane follows from where
    the pixel's line through vp crosses the segment's reference row; for 2/3 the
    roles of x and y swap.  Pixels map to the nearest plane.

    Returns:
        ``(plane (H, W) int32, row (H, W) int32, ok (H, W) bool)``.
    """
    st, i, _, row, ok = _ray_buffer_texel(cam, seg)
    return st + i, row, ok


def _box_hit(rle, fields, origins, dirs):
    """Pixel ray vs the box of a drawn element: ``(t_enter, t_exit)`` per pixel.

    ``fields`` = ``(top, bottom, cell x, cell z, level)`` arrays.  Written per
    axis: XLA:CPU runs stacked ``(H, W, 3)`` min/max reductions slowly.
    """
    top, bottom, ix, iz, lev = fields
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    cy = _cell_height(rle, c)
    lo = (ix.astype(jnp.float32) * c, bottom.astype(jnp.float32) * cy, iz.astype(jnp.float32) * c)
    hi = (lo[0] + c, (top + 1).astype(jnp.float32) * cy, lo[2] + c)
    t_enter, t_exit = -jnp.inf, jnp.inf
    for k in range(3):
        inv = _safe_div(1.0, dirs[..., k], 1e-12)
        t0 = (lo[k] - origins[..., k]) * inv
        t1 = (hi[k] - origins[..., k]) * inv
        t_enter = jnp.maximum(t_enter, jnp.minimum(t0, t1))
        t_exit = jnp.minimum(t_exit, jnp.maximum(t0, t1))
    return t_enter, t_exit


def _nearest_candidate(rle, lookup, color_of, origins, dirs, *, neighbors: int):
    """The warp's per-pixel choice among its texel and the adjacent planes' (4.5.5, 4.5.6).

    A pixel's ray lies between two planes, so its first voxel need not be the
    one its nearest texel saw (voxel edges, silhouettes).  With
    ``neighbors = k > 0`` the pixel also tests the elements of the same row in
    the ``k`` planes on either side and keeps the nearest box its own ray
    actually enters: the thesis filters the ray-buffer texture when it warps
    (4.5.6); here the filter is an exact per-pixel intersection instead of a
    blend, so colours are never mixed.  Every candidate is a real surface run,
    so the result is never in front of the true first hit; a pixel whose ray
    enters none of them keeps its nearest texel's element (the point of the
    ray closest to that box).

    Args:
        rle: the scene.
        lookup: ``lookup(plane offset (..., H, W) int32) -> (hit, index, box)``:
            each pixel's candidate in the plane that far from its nearest one
            (``box``: ``(top, bottom, cell x, cell z, level)``).
        color_of: ``color_of(index)``: the colour index of a candidate's top voxel.
        origins, dirs: (H, W, 3) pixel rays.
        neighbors: static planes on either side tested per pixel.

    Returns:
        ``(color (H, W, 3), depth (H, W), entered (H, W) bool)``: the nearest box
        the pixel's own ray enters (the nearest texel's where it enters none).
    """

    def candidate_t(hit, box):
        t_enter, t_exit = _box_hit(rle, box, origins, dirs)
        entered = hit & (t_enter <= t_exit) & (t_exit >= 0.0)
        return jnp.where(entered, jnp.maximum(t_enter, 0.0), jnp.inf)

    # All candidates at once, nearest texel first (it wins ties).
    off_list = [0] + [d for d in range(-neighbors, neighbors + 1) if d != 0]
    offs = jnp.asarray(off_list, jnp.int32)[:, None, None]
    cand_t = candidate_t(*lookup(offs)[::2])  # (2 neighbors + 1, H, W)
    best_t = jnp.min(cand_t, axis=0)
    best_d = offs[jnp.argmin(cand_t, axis=0), 0, 0]
    # Keep only the chosen plane offset and look it up again: XLA:CPU runs the
    # warp far slower carrying the candidate's index and depth together.
    best_d = jax.lax.optimization_barrier(best_d)
    hit, idx, box = lookup(best_d)
    t_enter, t_exit = _box_hit(rle, box, origins, dirs)
    color, depth = _shade(rle, hit, t_enter, t_exit, box, color_of(idx), origins, dirs)
    return color, depth, jnp.isfinite(best_t)


def _shade(rle, hit, t_enter, t_exit, box, cbase, origins, dirs):
    """Colour and depth where a pixel ray meets its chosen drawn element's box.

    A ray that enters the box takes its entry; one that passes beside it (between
    the sampled planes' voxels) the point of the box closest to it.
    """
    t_hit = jnp.maximum(jnp.where(t_enter <= t_exit, t_enter, 0.5 * (t_enter + t_exit)), 0.0)
    top, bottom, _, _, lev = box
    cy = _cell_height(rle, jnp.left_shift(1, lev).astype(jnp.float32))
    y_hit = origins[..., 1] + dirs[..., 1] * t_hit
    v = jnp.clip(jnp.floor(y_hit / cy).astype(jnp.int32), bottom, top)
    cidx = jnp.clip(cbase + (top - v), 0, rle.colors.shape[0] - 1)
    rgb = rle.colors[cidx].astype(jnp.float32) / 255.0
    return jnp.where(hit[..., None], rgb, 0.0), jnp.where(hit, t_hit, jnp.inf)


def warp_lists(
    rle,
    cam: Camera,
    seg: Segments,
    pool,
    start,
    drawn,
    coverage,
    first=None,
    *,
    neighbors: int = 1,
    tile: int = 8,
    batch_tiles: int | None = None,
    scan_width: int = 1,
    with_steps: bool = False,
):
    """Displays the ray buffer from the wide traversal's lists (4.5.5, Eq. 4.6).

    Every screen pixel looks up its texel (:func:`ray_buffer_coords`) and
    intersects its own ray with the texel's writer, the first element of its
    plane's list covering the row, so the colour along the element is
    perspective correct and the depth exact for the pixel; with ``neighbors``
    it also tests the adjacent planes' texels (:func:`_nearest_candidate`'s
    choice).  The cost follows the pixels the scene covers rather than the
    screen.  A cheap full-screen pass tests each pixel's
    candidate texels against the planes' 1-bit coverage maps; only the
    ``tile x tile`` screen tiles holding a covered pixel are warped, a batch of
    tiles per loop step.  A candidate texel's writer is found by scanning its
    plane's list front to back for the first element covering the row, from the
    first entry that drew in the row's coverage word when ``first`` is given
    (a row no entry drew is skipped), so neither the per-texel index array nor
    the coverage trees are built.

    Args:
        pool, start, drawn, coverage: the lists (``(5, N)`` words, each plane's
            from its ``start``, ``drawn`` long) and the planes' coverage maps
            from :func:`~jaxgfx._src.voxel.wide.traverse_wide`.
        first: optional (P, W) int32, each coverage word's first drawing entry
            (:func:`~jaxgfx._src.voxel.wide.traverse_wide`); None scans every list
            from its head.  The same frame either way.
        neighbors: static number of planes on either side tested per pixel
            (0 = the nearest texel only, as in the thesis).
        tile: static screen tile side in pixels (speed only).
        batch_tiles: static tiles warped per loop step (None: ``4096 / tile^2``;
            at least the screen's tile count: every busy tile in one step, so the
            warp's dependent steps are one list scan).
        scan_width: static list entries a pixel tests per loop step (the same
            frame; fewer, wider steps).
        with_steps: also return the dependent loop steps taken (list-scan steps
            summed over the batches).

    Returns:
        ``(color (H, W, 3), depth (H, W), entered (H, W) bool)``, ``entered``
        False where the pixel's ray entered none of its candidate boxes (it
        keeps its nearest texel's element), and ``steps`` () int32 with
        ``with_steps``.
    """
    P, cap = coverage.shape[0], pool.shape[1]
    n_words = coverage.shape[1]
    n_rows = 32 * n_words
    H, W = cam.height, cam.width
    flat = pool.reshape(-1)
    cov_flat = coverage.reshape(-1)
    first_flat = None if first is None else first.reshape(-1)
    offs = [0] + [d for d in range(-neighbors, neighbors + 1) if d != 0]

    def candidates(px, py):
        st, i0, cnt, row, ok = _texel_at(cam, seg, px, py)
        row_ok = ok & (row >= 0) & (row < n_rows)
        row = jnp.clip(row, 0, n_rows - 1)
        last = jnp.maximum(cnt - 1, 0)
        planes = jnp.stack([jnp.clip(st + jnp.clip(i0 + d, 0, last), 0, P - 1) for d in offs])
        return row_ok, row, planes

    # Which pixels can see a drawn element at all (their candidates' coverage bits).
    px0 = jnp.arange(W, dtype=jnp.float32)[None, :] + 0.5
    py0 = jnp.arange(H, dtype=jnp.float32)[:, None] + 0.5
    row_ok, row, planes = candidates(px0, py0)
    words = jnp.take(cov_flat, planes * n_words + (row >> 5)[None], mode="clip")
    bits = (words >> (row & 31).astype(jnp.uint32)[None]) & jnp.uint32(1)
    covered = row_ok & jnp.any(bits != 0, axis=0)
    ty, tx = -(-H // tile), -(-W // tile)
    n_tiles = ty * tx
    covered = jnp.pad(covered, ((0, ty * tile - H), (0, tx * tile - W)))
    busy = jnp.any(covered.reshape(ty, tile, tx, tile), axis=(1, 3)).reshape(-1)
    batch = max(1, 4096 // (tile * tile)) if batch_tiles is None else min(batch_tiles, n_tiles)
    n_batches = -(-n_tiles // batch)
    ids = jnp.nonzero(busy, size=n_batches * batch, fill_value=n_tiles)[0]
    n_busy = jnp.sum(busy.astype(jnp.int32))
    right, up, forward = camera_basis(cam)
    ar = jnp.arange(tile, dtype=jnp.int32)

    def warp_batch(b, carry):
        bufs, steps = carry
        tid = jax.lax.dynamic_slice(ids, (b * batch,), (batch,))
        y = (tid // tx * tile)[:, None, None] + ar[None, :, None]
        x = (tid % tx * tile)[:, None, None] + ar[None, None, :]
        px = jnp.broadcast_to(x, (batch, tile, tile)).astype(jnp.float32) + 0.5
        py = jnp.broadcast_to(y, (batch, tile, tile)).astype(jnp.float32) + 0.5
        row_ok, row, planes = candidates(px, py)
        gx, gy = screen_to_camera(cam, px, py)
        dirs = gx[..., None] * right + gy[..., None] * up + forward
        origins = jnp.broadcast_to(cam.position, dirs.shape)
        n = jnp.where(row_ok[None], drawn[planes], 0)
        base = start[planes]
        none = jnp.int32(NO_ENTRY)
        if first is None:
            j0 = jnp.zeros(n.shape, jnp.int32)
        else:
            # A drawn row's writer is at or after its word's first drawing entry;
            # an undrawn row has none (its scan starts past the list's end).
            at = planes * n_words + (row >> 5)[None]
            bit = jnp.take(cov_flat, at, mode="clip") >> (row & 31).astype(jnp.uint32)[None]
            j0 = jnp.where((bit & 1) != 0, jnp.take(first_flat, at, mode="clip"), n)

        # The first list element covering the row (lists run front to back).  The
        # scan stops once no pixel of the batch is still looking, not at the longest
        # list's end.
        # Each step tests scan_width entries, in list order.
        def scan_list(state):
            step, entry, _ = state
            j = j0 + step * scan_width
            for u in range(scan_width):
                at = base + (WORD_ROWS * cap + j + u)
                r0, r1 = unpack_drawn_rows(jnp.take(flat, at, mode="clip"))
                found = (entry == none) & (j + u < n) & (r0 <= row) & (row < r1)
                entry = jnp.where(found, j + u, entry)
            return step + 1, entry, jnp.any((entry == none) & (j + scan_width < n))

        init = (jnp.int32(0), jnp.full(n.shape, none), jnp.any(j0 < n))
        taken, entry, _ = jax.lax.while_loop(lambda s: s[2], scan_list, init)
        hit = entry < none
        idx = base + jnp.where(hit, entry, 0)
        word = lambda k, i: jnp.take(flat, i + k * cap, mode="clip")  # noqa: E731
        box = unpack_drawn_box(*(word(k, idx) for k in (WORD_HEIGHTS, WORD_X, WORD_Z_LEVEL)))
        t_enter, t_exit = _box_hit(rle, box, origins, dirs)
        entered = hit & (t_enter <= t_exit) & (t_exit >= 0.0)
        cand_t = jnp.where(entered, jnp.maximum(t_enter, 0.0), jnp.inf)
        # Nearest candidate the ray enters; the nearest texel wins ties and
        # keeps the pixel where the ray enters none.
        best = jnp.argmin(cand_t, axis=0)[None]
        pick = lambda a: jnp.take_along_axis(a, best, axis=0)[0]  # noqa: E731
        box_b = tuple(pick(v) for v in box)
        t_enter, t_exit = _box_hit(rle, box_b, origins, dirs)
        color, depth = _shade(
            rle, pick(hit), t_enter, t_exit, box_b, word(WORD_COLOR, pick(idx)), origins, dirs
        )
        out = (color, depth, jnp.any(entered, axis=0))
        # Tile ids past the busy ones are n_tiles: dropped.
        bufs = tuple(
            buf.at[tid].set(v.reshape((batch,) + buf.shape[1:]), mode="drop")
            for buf, v in zip(bufs, out)
        )
        return bufs, steps + taken

    # The frame as tile x tile blocks of pixels, row by row: nothing drawn yet.
    bufs = (
        jnp.zeros((n_tiles, tile * tile, 3), jnp.float32),
        jnp.full((n_tiles, tile * tile), jnp.inf, jnp.float32),
        jnp.zeros((n_tiles, tile * tile), bool),
    )
    bufs, steps = jax.lax.fori_loop(
        0, (n_busy + batch - 1) // batch, warp_batch, (bufs, jnp.int32(0))
    )

    def image(buf):
        img = buf.reshape((ty, tx, tile, tile) + buf.shape[2:]).swapaxes(1, 2)
        return img.reshape((ty * tile, tx * tile) + buf.shape[2:])[:H, :W]

    out = tuple(image(b) for b in bufs)
    return out + (steps,) if with_steps else out


# ---------------------------------------------------------------------------
# Per-pixel re-walk (not in the thesis)
# ---------------------------------------------------------------------------


def _voxel_lookup(rle, x, y, z):
    """(solid, colour index) of level-0 voxel (x, y, z) by decoding its RLE column."""
    L, off, sx, sy, sz = _level_tables(rle)
    Y = rle.level_shapes[0][1]
    in_map, has_tile, col = _map_column(rle, x, z, 0, off, sx, sz)
    has = in_map & has_tile
    inside = has & (y >= 0) & (y < Y)
    n, top, bottom, valid, drawn_before = _column_elements(rle, col, inside, Y, rle.max_elements)
    hit = valid & (y <= top) & (y >= bottom)
    j = jnp.argmax(hit)
    cidx = rle.color_ptr[jnp.where(inside, col, 0)].astype(jnp.int32) + drawn_before[j]
    return inside & jnp.any(hit), cidx + top[j] - y


def refine_pixel(rle, origin, direction, t_start, *, steps: int):
    """Exact first hit of ONE pixel ray near a known depth (short 3-D DDA in the RLE).

    Not part of the thesis: the ray buffer samples each pixel's nearest plane,
    which can pick a neighbouring voxel at voxel edges; this pass re-walks the
    pixel's own ray for ``steps`` voxels from ``t_start`` (a little before the
    depth found in the 3x3 neighbourhood), decoding RLE columns on the way.

    Returns:
        ``(found (), t (), colour index ())``; t is in units of ``direction``.
    """
    inv, t_enter, t_exit, idx, step, tiny = _dda_entry(rle.shape, origin, direction, t_start)
    dmax = jnp.asarray(rle.shape, jnp.int32) - 1

    def body(carry, _):
        idx, t, done, found, cidx = carry
        solid, ci = _voxel_lookup(rle, idx[0], idx[1], idx[2])
        now = ~done & solid
        nxt = ((idx + (direction > 0)).astype(jnp.float32) - origin) * inv
        nxt = jnp.where(tiny, jnp.inf, nxt)
        ax = jnp.argmin(nxt)
        idx_n = idx.at[ax].add(step[ax])
        out = jnp.any(idx_n < 0) | jnp.any(idx_n > dmax)
        done_n = done | now | out
        return (
            jnp.where(done_n, idx, idx_n),
            jnp.where(done_n, t, nxt[ax]),
            done_n,
            found | now,
            jnp.where(now, ci, cidx),
        ), None

    init = (idx, t_enter, t_enter > t_exit, jnp.bool_(False), jnp.int32(0))
    (_, t, _, found, cidx), _ = jax.lax.scan(body, init, None, length=steps)
    return found, t, cidx


def refine_hits(
    rle,
    cam: Camera,
    color,
    depth,
    *,
    steps: int,
    margin: float = 2.0,
    mask=None,
    budget: int | None = None,
    batch: int = 1024,
):
    """Applies :func:`refine_pixel` to pixels with a hit in their 3x3 neighbourhood.

    Args:
        color: (H, W, 3), depth: (H, W) from the ray buffer warp.
        steps: static DDA steps per pixel.
        margin: start this far (ray units) before the neighbourhood's nearest depth.
        mask: optional (H, W) bool, refine only these pixels.
        budget: static; if set, only the first ``budget`` selected pixels (row
            major) are re-walked, gathered into one compact batch, so the cost
            is ``budget`` walks instead of ``H W``.
        batch: static pixels walked together; batches no pixel asked for are
            skipped (the walks of a frame take ``steps`` dependent steps per batch).

    Returns:
        ``(color, depth, selected)`` with exact hits where the short walk found
        one; ``selected`` () int32 counts the pixels that asked for a walk
        (those beyond ``budget`` keep the warp's result).
    """
    H, W = depth.shape
    near = jax.lax.reduce_window(depth, jnp.inf, jax.lax.min, (3, 3), (1, 1), "SAME")
    origins, dirs = pixel_rays(cam, normalize=False)
    start = jnp.where(jnp.isfinite(near), jnp.maximum(near - margin, 0.0), 0.0)
    want = jnp.isfinite(near) if mask is None else mask & jnp.isfinite(near)
    fn = lambda o, d, t: refine_pixel(rle, o, d, t, steps=steps)  # noqa: E731
    n = H * W
    if budget is None or budget >= n:
        found, t, cidx = jax.vmap(fn)(origins.reshape(n, 3), dirs.reshape(n, 3), start.ravel())
        found = found & want.ravel()
        idx = jnp.arange(n)
    else:
        idx = jnp.nonzero(want.ravel(), size=budget, fill_value=n)[0]
        asked = jnp.sum(want)

        def walk(part):
            safe = jnp.minimum(part, n - 1)
            o, d, t0 = origins.reshape(n, 3)[safe], dirs.reshape(n, 3)[safe], start.ravel()[safe]
            f, t, ci = jax.vmap(fn)(o, d, t0)
            return f & (part < n), t, ci

        def skip(part):
            z = jnp.zeros(part.shape, jnp.int32)
            return jnp.zeros(part.shape, bool), z.astype(jnp.float32), z

        # Walk in batches and skip the batches no pixel asked for, so the cost
        # follows the number of uncertain pixels, not the budget.
        outs = [
            jax.lax.cond(asked > a, walk, skip, idx[a : a + batch]) for a in range(0, budget, batch)
        ]
        found, t, cidx = (jnp.concatenate([o[k] for o in outs]) for k in range(3))
    dest = jnp.where(found, idx, n)
    rgb = rle.colors[jnp.clip(cidx, 0, rle.colors.shape[0] - 1)].astype(jnp.float32) / 255.0
    color = color.reshape(n, 3).at[dest].set(rgb, mode="drop").reshape(H, W, 3)
    depth = depth.ravel().at[dest].set(t, mode="drop").reshape(H, W)
    return color, depth, jnp.sum(want).astype(jnp.int32)
