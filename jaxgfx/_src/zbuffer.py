"""The z-buffer kernel of :mod:`jaxgfx.raster`: clipping, triangle setup, visibility.

:func:`visible_faces` finds the nearest face per pixel of one frame; under ``jax.vmap`` a batch
follows the batching rule of :mod:`jaxgfx._src.frames` (frame by frame on XLA:CPU, where each
frame's buffers stay in cache; one vectorized program elsewhere).  :func:`visibility` can also
take the setups of several frames laid one after the other (``frames=B``, one B*H*W
z-buffer).

Results do not depend on how the work is cut into chunks or frames: a pixel keeps the largest
1/z (compared as int32 bit patterns, exact) and, among exact ties, the smallest face index.  So
a frame rendered alone and the same frame inside a batch see the same faces.

Fragments are generated per chunk of the (triangle, tile) work list as (block^2, K) planes over
contiguous rows, which XLA:CPU vectorises; faces are set up and z-buffered :data:`TRI_BATCH` at a
time so a large mesh's temporaries stay small (fresh pages cost a fault each); the second
triangles of near-plane clipping are set up only for face batches that cross the plane.  The
measurements behind these choices are in the design notes (``docs/design/engine.md``).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, focal_lengths, world_to_camera_soa
from jaxgfx._src.compaction import running_sum
from jaxgfx._src.frames import check_batching, per_frame

__all__ = [
    "ClippedTriangles",
    "TriangleSetup",
    "corners_soa",
    "clip_near",
    "triangle_setup",
    "visibility",
    "visible_faces",
    "NO_TRI",
    "CHUNK",
    "TRI_BATCH",
]

NO_TRI = np.int32(np.iinfo(np.int32).max)  # face id of an empty pixel
_OUT = np.int32(np.iinfo(np.int32).max)  # pixel index of a rejected fragment (dropped)
# Faces per setup batch (see _frame_visibility): ~26 MB of setup temporaries, under
# glibc's largest mmap threshold (32 MB), so the buffers are reused between calls.  Each
# batch ends with a partly filled chunk; 2^16 faces and chunks of 2^14 work items
# the fastest of (2^14..2^17 faces) x (2^13..2^15 items) on the bunny and the 718 k-face
# terrain (see the design notes).
TRI_BATCH = 1 << 16
CHUNK = 1 << 14  # work items (tiles) per z-buffer pass


class ClippedTriangles(NamedTuple):
    """Triangles after near-plane clipping; two output slots per input face.

    Structure-of-arrays layout (the face axis last) so that XLA vectorises the
    per-triangle arithmetic.
    """

    verts: jax.Array  # (3 coords, 3 corners, 2F) camera-space vertices
    valid: jax.Array  # (2F,) bool
    source: jax.Array  # (2F,) int32 index of the input face


class TriangleSetup(NamedTuple):
    """Per-triangle screen-space data, structure-of-arrays (triangle axis last).

    Kept SoA on purpose: a (T, 22) layout would need a transpose of the whole
    array, which costs more on XLA:CPU than gathering 22 rows per work item.  The
    rows are separate arrays, not one stacked (22, T) array: the setup's fusion
    writes each row once, where the stack cost a 5.8 MB copy per 2^16 faces.
    """

    packed: tuple[jax.Array, ...]  # 22 (T,) float32 rows, as in the _AX.._WFAR constants
    ints: tuple[jax.Array, ...]  # 6 (T,) int32 rows: lo_x, lo_y, hi_x, hi_y, nblocks_x, face
    nblocks: jax.Array  # (T,) int32 tiles in the bbox, 0 for culled triangles


# Column layout of TriangleSetup.packed: canonical edge start (ax, ay), edge
# direction (dx, dy) and inside sign for the 3 edges, then the 1/z plane, then the
# camera's 1/near and 1/far (per triangle, so one folded work list can hold the
# triangles of several cameras).
_AX, _AY, _DX, _DY, _SG = 0, 3, 6, 9, 12
_W0, _GX, _GY, _S0X, _S0Y = 15, 16, 17, 18, 19
_WNEAR, _WFAR = 20, 21


def corners_soa(cam: Camera, vertices: jax.Array, faces: jax.Array) -> jax.Array:
    """Camera-space triangle corners as (3 coords, 3 corners, F)."""
    pc = world_to_camera_soa(cam, vertices)  # (3, V)
    return pc[:, faces.T]


def clip_near(p_cam: jax.Array, near: jax.Array) -> ClippedTriangles:
    """Clips camera-space triangles against the plane ``z = near``.

    A triangle with one vertex in front keeps a smaller triangle; with two in
    front it becomes a quad split into two triangles; winding is preserved.
    The intersection point on an edge is computed from its (inside, outside)
    endpoints, so neighbours sharing the edge get the identical point.

    Args:
        p_cam: (3 coords, 3 corners, F) camera-space triangle vertices.
        near: () near-plane distance.

    Returns:
        :class:`ClippedTriangles` with 2F slots.
    """
    first, second = _clip_halves(p_cam, near)
    return ClippedTriangles(*(jnp.concatenate(x, axis=-1) for x in zip(first, second)))


def _clip_halves(p_cam, near):
    """:func:`clip_near` as its two halves: the first triangle of every face (F slots),
    and the second one that a face with two corners in front of the plane adds."""
    f = p_cam.shape[-1]
    inside = p_cam[2] >= near  # (3, F)
    n_in = inside.sum(0)
    # Rotate so the odd vertex (the lone inside one, or the lone outside one)
    # comes first; a cyclic rotation keeps the winding.
    odd = jnp.where(n_in == 1, inside, ~inside)
    k = jnp.where(odd[0], 0, jnp.where(odd[1], 1, 2))

    def corner(j):  # corner (k + j) % 3, as (3 coords, F)
        c0, c1, c2 = p_cam[:, j % 3], p_cam[:, (j + 1) % 3], p_cam[:, (j + 2) % 3]
        return jnp.where(k == 0, c0, jnp.where(k == 1, c1, c2))

    v0, v1, v2 = corner(0), corner(1), corner(2)

    def cut(p_in, p_out):
        dz = p_out[2] - p_in[2]
        safe = jnp.where(jnp.abs(dz) > 0, dz, 1.0)
        t = jnp.clip((near - p_in[2]) / safe, 0.0, 1.0)
        q = p_in + t * (p_out - p_in)
        return q.at[2].set(jnp.maximum(q[2], near))

    i01 = cut(v1, v0)
    i20 = cut(v2, v0)
    one = (v0, cut(v0, v1), cut(v0, v2))  # one inside (v0): (v0, I01, I02)
    two_a = (i01, v1, v2)  # two inside (v0 out): (I01, v1, v2) + (I01, v2, I20)
    two_b = jnp.stack([i01, v2, i20], axis=1)
    all_in, one_in = n_in == 3, n_in == 1
    first = jnp.stack(
        [jnp.where(all_in, p_cam[:, j], jnp.where(one_in, one[j], two_a[j])) for j in range(3)],
        axis=1,
    )
    source = jnp.arange(f, dtype=jnp.int32)
    return ClippedTriangles(first, n_in > 0, source), ClippedTriangles(two_b, n_in == 2, source)


def triangle_setup(
    cam: Camera, tris: ClippedTriangles, keep: jax.Array, block: int
) -> TriangleSetup:
    """Screen-space setup: canonical edges, 1/z plane, pixel bbox and tile count.

    Args:
        cam: the camera (resolution is static).
        tris: clipped triangles.
        keep: (2F,) bool, extra per-slot mask (e.g. back-face culling).
        block: tile edge length in pixels.
    """
    flx, fly = focal_lengths(cam)
    x, y, z = tris.verts[0], tris.verts[1], tris.verts[2]  # (3 corners, T)
    z = jnp.where(tris.valid, z, 1.0)
    cx, cy = cam.principal[0], cam.principal[1]
    sx = jnp.where(tris.valid, cx + flx * x / z, 0.0)
    sy = jnp.where(tris.valid, cy - fly * y / z, 0.0)
    qx = jnp.stack([sx[1], sx[2], sx[0]])  # edge i: p_i -> p_{i+1}
    qy = jnp.stack([sy[1], sy[2], sy[0]])
    # Canonical direction: start at the endpoint lower on screen (larger y),
    # ties broken by smaller x, so both owners of an edge agree bit for bit.
    p_first = (sy > qy) | ((sy == qy) & (sx < qx))
    ax, ay = jnp.where(p_first, sx, qx), jnp.where(p_first, sy, qy)
    dx, dy = jnp.where(p_first, qx, sx) - ax, jnp.where(p_first, qy, sy) - ay
    e1x, e1y = sx[1] - sx[0], sy[1] - sy[0]
    e2x, e2y = sx[2] - sx[0], sy[2] - sy[0]
    area2 = e1x * e2y - e1y * e2x
    sign = jnp.where(p_first, 1.0, -1.0) * jnp.sign(area2)
    safe_area = jnp.where(area2 != 0, area2, 1.0)
    w = 1.0 / z
    dw1, dw2 = w[1] - w[0], w[2] - w[0]
    gx = (dw1 * e2y - dw2 * e1y) / safe_area
    gy = (dw2 * e1x - dw1 * e2x) / safe_area
    # Pixel i is covered only if its centre i + 0.5 lies in [min, max].
    lo_x = jnp.clip(jnp.ceil(_min3(sx) - 0.5), 0.0, cam.width).astype(jnp.int32)
    lo_y = jnp.clip(jnp.ceil(_min3(sy) - 0.5), 0.0, cam.height).astype(jnp.int32)
    hi_x = jnp.clip(jnp.floor(_max3(sx) - 0.5), -1.0, cam.width - 1.0).astype(jnp.int32)
    hi_y = jnp.clip(jnp.floor(_max3(sy) - 0.5), -1.0, cam.height - 1.0).astype(jnp.int32)
    ext_x = jnp.maximum(hi_x - lo_x + 1, 0)
    ext_y = jnp.maximum(hi_y - lo_y + 1, 0)
    nbx = (ext_x + block - 1) // block
    nby = (ext_y + block - 1) // block
    alive = tris.valid & keep & (area2 != 0) & (ext_x > 0) & (ext_y > 0)
    nblocks = jnp.where(alive, nbx * nby, 0).astype(jnp.int32)
    wlim = jnp.broadcast_to(1.0 / jnp.stack([cam.near, cam.far])[:, None], (2, w.shape[-1]))
    packed = (*ax, *ay, *dx, *dy, *sign, w[0], gx, gy, sx[0], sy[0], *wlim)
    ints = (lo_x, lo_y, hi_x, hi_y, jnp.maximum(nbx, 1), tris.source)
    return TriangleSetup(packed, ints, nblocks)


def _min3(a):
    """Minimum over the leading axis of 3 rows (row-wise: XLA:CPU reduces it slowly)."""
    return jnp.minimum(jnp.minimum(a[0], a[1]), a[2])


def _max3(a):
    """Maximum over the leading axis of 3 rows."""
    return jnp.maximum(jnp.maximum(a[0], a[1]), a[2])


def _chunk_fragments(cam, setup, starts, offsets, total, chunk0, chunk, block, tris_per_item=0):
    """Fragments of work items ``chunk0 .. chunk0+chunk``: (pixel index, 1/z, face id, ok).

    All four are (block*block, chunk): tile slot major, work item minor.  The pixel
    index is NOT masked by ``ok``: a rejected fragment may carry any index (in the frame
    or past its end), so callers neutralise it through its value (1/z bits 0, count 0).

    With ``tris_per_item > 0`` the setup holds the triangles of several frames one
    after the other (``tris_per_item`` each) and pixel indices address a stack of
    frames: frame ``t // tris_per_item`` starts at pixel ``(t // tris_per_item) * H * W``.
    """
    item = chunk0 + jnp.arange(chunk, dtype=jnp.int32)
    live = item < total
    t = jnp.minimum(_count_le(offsets, item), offsets.shape[0] - 1)
    # One 1-D gather per setup row: each lands in its own contiguous (K,) buffer, so the
    # fragment arithmetic below reads unit-stride rows and vectorises.  A (22, K) row
    # gather is laid out item-major by XLA:CPU and read with stride 22 (scalar code:
    # ~45 ns a fragment, against ~3 ns).
    row = [jnp.take(r, t, mode="clip") for r in setup.packed]
    irow = [jnp.take(r, t, mode="clip") for r in setup.ints]
    local = item - jnp.take(starts, t, mode="clip")
    nbx = irow[4]
    q = jax.lax.div(local, nbx)  # non-negative: truncating division, no floor fix-ups
    x0 = irow[0] + (local - q * nbx) * block
    y0 = irow[1] + q * block
    # Fragments as (block*block, K): every per-item row broadcasts along the leading
    # axis, unit stride along the minor one.
    ox = np.tile(np.arange(block, dtype=np.int32), block)[:, None]
    oy = np.repeat(np.arange(block, dtype=np.int32), block)[:, None]
    px = x0[None] + ox
    py = y0[None] + oy
    cx = px.astype(jnp.float32) + 0.5
    cy = py.astype(jnp.float32) + 0.5

    def col(i):
        return row[i][None]

    inside = live[None] & (px <= irow[2][None]) & (py <= irow[3][None])
    for e in range(3):
        # The edge function's two products, compared rather than subtracted: a
        # compiler that contracts ``a - b`` into a fused multiply-add (XLA:CPU's
        # emitters differ here, GPUs do it by default) rounds the two triangles of
        # a shared edge differently, while each product alone is one correctly
        # rounded multiply, the same bits for both.  Top-left rule: a centre
        # exactly on an edge belongs to the triangle on its canonical "+" side.
        a = col(_DX + e) * (cy - col(_AY + e))
        b = col(_DY + e) * (cx - col(_AX + e))
        inside = inside & jnp.where(col(_SG + e) > 0, a >= b, b > a)
    w = col(_W0) + col(_GX) * (cx - col(_S0X)) + col(_GY) * (cy - col(_S0Y))
    ok = inside & (w <= col(_WNEAR)) & (w >= col(_WFAR))
    pix = py * cam.width + px
    if tris_per_item:
        pix = pix + ((t // tris_per_item) * (cam.width * cam.height))[None]
    fid = jnp.broadcast_to(irow[5][None], pix.shape)
    # Not flattened: an XLA:CPU loop fusion whose result is reshaped to 1-D indexes it
    # linearly and stops vectorising; scatters take (B*B, K).
    return pix, w, fid, ok


def _count_le(sorted_x, q):
    """How many of ``sorted_x`` (non-decreasing, (N,)) are <= each query ``q`` (K,).

    ``jnp.searchsorted(sorted_x, q, side="right")`` as a branchless binary search: one
    gather-and-select per halving step on a single carried position, which XLA:CPU
    updates in place (``method="scan"`` carries two bounds and copied both each step).
    """
    n = sorted_x.shape[0]
    levels = max(n.bit_length(), 1)

    def halve(i, pos):
        step = jnp.left_shift(jnp.int32(1), levels - 1 - i)
        cand = pos + step
        ok = (cand <= n) & (jnp.take(sorted_x, cand - 1, mode="clip") <= q)
        return jnp.where(ok, cand, pos)

    return jax.lax.fori_loop(0, levels, halve, jnp.zeros(q.shape, jnp.int32))


def _work_list(nblocks):
    """Where each triangle's work items (tiles) start and end in the work list, and how
    many items there are: ``(starts, offsets, total)`` (``offsets`` inclusive)."""
    offsets = running_sum(nblocks)
    total = offsets[-1] if nblocks.shape[0] else jnp.int32(0)
    return offsets - nblocks, offsets, total


def visibility(
    cam: Camera, setup: TriangleSetup, block: int, chunk: int, frames: int = 1
) -> tuple[jax.Array, jax.Array]:
    """Nearest face per pixel by a chunked z-buffer over (triangle, tile) work items.

    Args:
        cam: the camera (only its static resolution is used: near/far are in the setup).
        setup: triangle setup, ``T = frames * tris_per_frame`` triangles, frame-major.
        block: tile edge in pixels (static).
        chunk: work items per z-buffer pass (static).
        frames: how many frames the setup holds (static).

    Returns:
        ``(inv_depth, face_id)`` flat (frames*H*W,): the largest 1/z (0 where empty)
        and the smallest face index at that 1/z (``NO_TRI`` where empty).
    """
    npix = frames * cam.width * cam.height
    zbuf = jnp.zeros((npix,), jnp.int32)
    ibuf = jnp.full((npix,), NO_TRI, jnp.int32)
    zbuf, ibuf = _zbuffer(cam, setup, block, chunk, frames, zbuf, ibuf)
    return jax.lax.bitcast_convert_type(zbuf, jnp.float32), ibuf


def _zbuffer(cam, setup, block, chunk, frames, zbuf, ibuf):
    """:func:`visibility` continuing from z-buffer ``zbuf`` (1/z bits) and face buffer ``ibuf``."""
    n_tris = setup.nblocks.shape[0]
    per_frame = n_tris // frames if frames > 1 else 0
    starts, offsets, total = _work_list(setup.nblocks)
    n_frag = (block * block, chunk)

    def fragments(c0):
        pix, w, fid, ok = _chunk_fragments(
            cam, setup, starts, offsets, total, c0, chunk, block, per_frame
        )
        # The z-buffer holds the bit patterns of 1/z as int32: for positive
        # floats they order like the values and an integer max is exact.
        wb = jax.lax.bitcast_convert_type(jnp.where(ok, w, 0.0), jnp.int32)
        # A rejected fragment keeps its (unmasked) pixel index: its 1/z bits are 0,
        # which neither raises the z-buffer nor wins (win needs wb > 0).
        return pix, wb, fid

    def no_fragments(c0):
        del c0
        return (
            jnp.full(n_frag, _OUT, jnp.int32),
            jnp.zeros(n_frag, jnp.int32),
            jnp.zeros(n_frag, jnp.int32),
        )

    # Software-pipelined loop: iteration k computes the fragments of chunk k
    # into the loop carry and z-tests those of chunk k-1 from the carry.  The
    # scatter and the winner test below must see bit-identical depths; a loop
    # carry is a materialised buffer, whereas values inside one iteration may
    # be recomputed by two XLA fusions with different FMA contraction (and
    # XLA:CPU drops optimization barriers).  The last iteration has no chunk
    # left to compute, and skips it.
    def cond(state):
        return state[0] < total + chunk

    def body(state):
        c0, zbuf, ibuf, pix, wb, fid, old = state
        zbuf = zbuf.at[pix].max(wb, mode="drop")
        best = zbuf.at[pix].get(mode="fill", fill_value=-1)
        win = (wb == best) & (wb > 0)  # out of the frame: best is -1
        # Where this chunk brought a pixel nearer, the face found before is void;
        # then the smallest face index among the chunk's exact ties wins.  Every
        # step touches only this chunk's fragments, never the whole frame.
        ibuf = ibuf.at[jnp.where(win & (best > old), pix, _OUT)].set(NO_TRI, mode="drop")
        ibuf = ibuf.at[jnp.where(win, pix, _OUT)].min(fid, mode="drop")
        # The next chunk's fragments depend on the z-test's result (a test that never
        # holds: face ids are >= 0), so XLA schedules them after the scatters have read
        # this chunk's: they can then overwrite the loop carry in place, where XLA:CPU
        # copied the three (B*B, K) carries every iteration (it drops optimization
        # barriers).
        c_next = jnp.where(ibuf[0] == -1, total, c0)
        nxt = jax.lax.cond(c_next < total, fragments, no_fragments, c_next)
        return (c0 + chunk, zbuf, ibuf, *nxt, zbuf.at[nxt[0]].get(mode="fill", fill_value=0))

    state = (jnp.int32(0), zbuf, ibuf, *no_fragments(0), jnp.zeros(n_frag, jnp.int32))
    _, zbuf, ibuf, *_ = jax.lax.while_loop(cond, body, state)
    return zbuf, ibuf


def _frame_setup(cam, vertices, faces, cull_backfaces, block, p_cam, half=None):
    """Clipping and setup of one frame (camera, vertices and faces of one item).

    ``p_cam``: the vertices in camera space as (3, V) (``world_to_camera_soa``); the world
    positions are read only for back-face culling.  ``half``: 0 or 1 sets up only that half
    of the clipped slots (see :func:`_clip_halves`); ``None`` both, as :func:`clip_near`
    lays them out.
    """
    corners = p_cam[:, faces.T]
    if half == "front":  # no face crosses the plane: no clipping arithmetic
        n_in = (corners[2] >= cam.near).sum(0)
        source = jnp.arange(faces.shape[0], dtype=jnp.int32)
        tris = ClippedTriangles(corners, n_in == 3, source)
        half = 0
    else:
        halves = _clip_halves(corners, cam.near)
        if half is None:
            tris = ClippedTriangles(*(jnp.concatenate(x, axis=-1) for x in zip(*halves)))
        else:
            tris = halves[half]
    if cull_backfaces:
        tri_w = vertices[faces]
        n = jnp.cross(tri_w[:, 1] - tri_w[:, 0], tri_w[:, 2] - tri_w[:, 0])
        front = jnp.sum(n * (tri_w[:, 0] - cam.position), -1) < 0
        keep = front if half is not None else jnp.concatenate([front, front])
    else:
        keep = jnp.ones(tris.valid.shape, bool)
    return triangle_setup(cam, tris, keep, block)


def _frame_visibility(cam, vertices, p_cam, faces, cull_backfaces, block, chunk, tri_batch):
    """Visibility of one frame, its faces set up ``tri_batch`` at a time.

    ``p_cam``: (3, V) camera-space vertices (``world_to_camera_soa``), computed once by the
    caller, which may shade from the same array.

    A frame's setup holds ~200 bytes per face; for a large mesh (the 718 k-face terrain:
    ~300 MB of temporaries) XLA:CPU's per-call buffers then come fresh from the OS and
    touching them (a page fault per 4 KiB) costs as much as the rasterization.
    Setting up and z-buffering the faces in batches bounds the temporaries, and the
    result is the same: the z-buffer keeps the largest 1/z and the smallest face id
    among exact ties whatever the order.  For the same reason each batch draws the first
    triangle of every face, then the second triangles that near-plane clipping makes only
    if a face of the batch has two corners in front of the plane: otherwise that half of
    the slots is all empty, and setting it up is a large share of a terrain frame.  A batch
    with no face crossing the plane skips the clipping arithmetic too.
    """
    n = faces.shape[0]
    batches = max(1, -(-n // tri_batch))
    size = -(-n // batches)
    # The last batch's window is moved back to end at the last face (no padded copy
    # of the faces); its faces before b * size were drawn by the batch before.
    done = jnp.arange(size, dtype=jnp.int32)  # face of each setup slot

    def body(b, bufs):
        first = jnp.minimum(b * size, n - size)
        part = jax.lax.dynamic_slice_in_dim(faces, first, size)
        n_in = (p_cam[2][part] >= cam.near).sum(-1)

        def setup_of(half):
            # Half 0 without clipping arithmetic where no face crosses the plane.
            front = ~jnp.any((n_in > 0) & (n_in < 3))
            kind = jnp.where(half == 1, 2, jnp.where(front, 1, 0))
            args = (cam, vertices, part, cull_backfaces, block, p_cam)
            return jax.lax.switch(
                kind, [functools.partial(_frame_setup, *args, h) for h in (0, "front", 1)]
            )

        def draw(half, bufs):
            setup = setup_of(half)
            setup = TriangleSetup(
                setup.packed,
                (*setup.ints[:5], setup.ints[5] + first),
                jnp.where(done < b * size - first, 0, setup.nblocks),
            )
            return _zbuffer(cam, setup, block, chunk, 1, *bufs)

        # One z-buffer loop (traced once: compile time) over 1 or 2 halves.
        halves = 1 + jnp.any(n_in == 2).astype(jnp.int32)
        return jax.lax.fori_loop(0, halves, draw, bufs)

    npix = cam.width * cam.height
    bufs = (jnp.zeros((npix,), jnp.int32), jnp.full((npix,), NO_TRI, jnp.int32))
    if batches == 1:
        zbuf, ibuf = body(0, bufs)
    else:
        zbuf, ibuf = jax.lax.fori_loop(0, batches, body, bufs)
    return jax.lax.bitcast_convert_type(zbuf, jnp.float32), ibuf


@functools.cache
def _visible_faces_fn(cull_backfaces: bool, block: int, chunk: int, tri_batch: int, batching: str):
    """The batching kernel for one static configuration (built once, cached)."""

    def frame(cam, vertices, faces):  # (1/z, face id), each flat (H*W,)
        p_cam = world_to_camera_soa(cam, vertices)
        return _frame_visibility(
            cam, vertices, p_cam, faces, cull_backfaces, block, chunk, tri_batch
        )

    return per_frame(frame, batching)


def visible_faces(
    cam: Camera,
    vertices: jax.Array,
    faces: jax.Array,
    *,
    cull_backfaces: bool = False,
    block: int = 2,
    chunk: int = CHUNK,
    tri_batch: int = TRI_BATCH,
    batching: str = "auto",
) -> tuple[jax.Array, jax.Array]:
    """Nearest face per pixel of one frame (no gradients flow through it).

    Under ``jax.vmap`` the frames follow ``batching`` (:func:`jaxgfx._src.frames.per_frame`):
    on XLA:CPU one after the other, where each frame's z-buffer (H*W int32 twice) stays in
    cache (one folded B*H*W z-buffer is slower: random scatters over the whole batch's
    buffers); elsewhere as one program over the batch.

    Args:
        cam: the camera; static resolution.
        vertices: (V, 3) world positions.
        faces: (F, 3) int32 vertex indices.
        cull_backfaces, block, chunk: as in :func:`jaxgfx.raster.rasterize` (static).
        tri_batch: faces set up and z-buffered at a time (static); bounds a frame's
            temporaries for large meshes without changing the result.
        batching: the ``vmap`` rule, one of ``"auto"``, ``"frames"``, ``"vectorized"``.

    Returns:
        ``(inv_depth, face_id)``, each (H*W,): the largest 1/z (0 where empty) and the face
        index (``NO_TRI`` where empty).
    """
    fn = _visible_faces_fn(
        bool(cull_backfaces), int(block), int(chunk), int(tri_batch), check_batching(batching)
    )
    return fn(cam, vertices, faces)
