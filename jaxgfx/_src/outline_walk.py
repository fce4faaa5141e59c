"""The outline walk of analytic antialiasing: which silhouette edge lies between two pixels.

For a pair of neighbouring pixel centres that see different triangles, the segment between
them is followed from the front pixel's triangle across interior edges into the adjacent faces
until it crosses a silhouette edge (the pair blends there) or reaches the other centre (no
outline between them); see :mod:`jaxgfx._src.silhouette` for the blend.  The walk is discrete
and carries no gradient.

**Work in proportion to the walks.**  Only pairs whose pixels see different triangles near
a silhouette edge can blend (:func:`near_silhouettes`), and few of those reach an outline; the
others end in the first few faces.  So the candidate pairs of both axes are compacted into one
queue (:func:`jaxgfx._src.compaction.compact`), and a pool of ``lanes`` walks runs
``_ROUND`` faces a step: each step every lane crosses its faces, and the lanes whose walk
ended take the next walks from the queue.  A step costs the pool's width whatever the walks'
lengths, and the pool is busy until the queue runs dry, so the frame's work is about its
total number of faces crossed plus one pool's width per face of the longest walk left at the
end.  Walks that cross an outline are listed as they end; with a background, each such walk
between two covered pixels queues the walk from the other pixel's surface towards the front
one (the gap test).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxgfx._src.compaction import compact, running_sum

__all__ = [
    "MAX_HOPS",
    "OutlineHits",
    "edge_plane",
    "edge_planes",
    "find_outlines",
    "front_is_a",
    "near_silhouettes",
    "pair_pixels",
]

MAX_HOPS = 16
"""Faces beyond the first that the walk from a pixel's triangle towards its neighbour's centre
may cross.

Beside an outline the surface is seen nearly edge-on, so several thin faces can lie between two
pixel centres; a pair whose outline is further than this many faces away is left unblended.
"""

# Crossings this far (in pixel steps) past the other pixel's centre still blend, clamped to it:
# the rasterizer's coverage test and the plane test here round differently.
_PAST_CENTRE = 1.0 / 16.0


class OutlineHits(NamedTuple):
    """What the walks of one frame found (:func:`find_outlines`); ``Q = 2 H W`` pair slots.

    Attributes:
        pairs: (Q,) int32, the candidate pairs in queue order (pair ``p < H W`` is pixel ``p``
            and its right neighbour, ``p >= H W`` pixel ``p - H W`` and the one below), padded
            with ``Q``.
        face: (2, Q) int32, per queue slot the face holding the silhouette edge crossed by the
            walk from the front pixel (row 0) and by the walk back from the other pixel (row 1;
            walked only with a background, where row 0 crossed one and both pixels are
            covered); -1 where none was crossed or walked.
        edge: (2, Q) int32, that edge's index in the face.
        hits: (Q,) int32, the slots whose front walk crossed an outline, in the order the walks
            ended, padded with ``Q``.
        hit_count: () int32, how many slots ``hits`` lists.
    """

    pairs: jax.Array
    face: jax.Array
    edge: jax.Array
    hits: jax.Array
    hit_count: jax.Array


def edge_planes(p_cam, faces, across):
    """Per face and edge: the inward normal of the edge's eye plane, and where the walk goes next.

    Args:
        p_cam: (V, 3) camera-space vertices; faces (F, 3); across (F, 3) from
            :func:`jaxgfx.silhouette.silhouette_edges`.

    Returns:
        ``(normals (F, 9), onward (F, 3) int32)``: edge ``e``'s normal in columns ``3 e`` to
        ``3 e + 2``, oriented so that the face's own third vertex has a positive dot product,
        and zero for a face seen edge-on (then no ray is inside).  ``onward`` is the face
        across the edge, or -1 where the edge is a silhouette edge (boundary, or the face across
        folds back).  Coordinates are gathered one array at a time: XLA:CPU gathers scalars
        from flat arrays about twice as fast as rows of three.
    """
    x, y, z = p_cam[:, 0], p_cam[:, 1], p_cam[:, 2]
    other = jnp.maximum(across, 0)
    # The far vertex of the face across: the corner after the shared edge's end in that face.
    far = faces.reshape(-1)[3 * (other // 3) + (other % 3 + 2) % 3]  # (F, 3)
    corners = [(x[faces[:, i]], y[faces[:, i]], z[faces[:, i]]) for i in range(3)]
    normals, onward = [], []
    for e in range(3):
        (px, py, pz), (qx, qy, qz), (kx, ky, kz) = (corners[(e + i) % 3] for i in range(3))
        # The normal of the plane through the eye and the edge, p x q, towards k.
        nx, ny, nz = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx
        side = jnp.sign(nx * kx + ny * ky + nz * kz)
        mx, my, mz = side * nx, side * ny, side * nz
        v = far[:, e]
        folds = mx * x[v] + my * y[v] + mz * z[v] >= 0
        normals += [mx, my, mz]
        onward.append(jnp.where((across[:, e] < 0) | folds, -1, other[:, e] // 3))
    return jnp.stack(normals, 1), jnp.stack(onward, 1).astype(jnp.int32)


def edge_plane(p_cam, faces, face, edge):
    """(N, 3): the normal of :func:`edge_planes` for edge ``edge`` of face ``face`` alone.

    The blends recompute the few crossed edges' planes with gradients, from their corners,
    rather than differentiate the table of every face's.
    """
    corners = p_cam[faces[jnp.maximum(face, 0)]]  # (N, 3, 3)
    rows = jnp.arange(face.shape[0])
    p, q, k = (corners[rows, (edge + i) % 3] for i in range(3))
    n = jnp.cross(p, q)
    return jnp.sign(jnp.sum(n * k, -1))[:, None] * n


def _hop(nrm, nxt_all, face, target, ray, step):
    """One step of the walk: where the segment leaves ``face``, and what lies beyond.

    Args:
        nrm: (N, 9) the edge-plane normals of ``face``; nxt_all: (N, 3) its walk table row
            (:func:`edge_planes`).
        face: (N,) the current faces, -1 for lanes without a walk.
        target: (N,) the other pixel's triangle (-1: none).
        ray, step: (N, 3) the segment's start ray and its step to the other pixel's ray.

    Returns:
        ``(hit, edge, onward_face)``, each (N,): whether the segment leaves ``face`` through a
        silhouette edge before (or just past) the other centre, that edge's index, and the face
        the walk continues in (-1 when it is over: an outline was crossed, the other centre is
        reached, or the face beyond is the other pixel's own, which holds that centre).
    """
    alive = face >= 0
    t_exit = jnp.full(face.shape, jnp.inf, nrm.dtype)
    e_exit = jnp.zeros_like(face)
    nxt = jnp.full_like(face, -1)
    for e in range(3):
        mx, my, mz = nrm[:, 3 * e], nrm[:, 3 * e + 1], nrm[:, 3 * e + 2]
        a = mx * ray[:, 0] + my * ray[:, 1] + mz * ray[:, 2]
        d = mx * step[:, 0] + my * step[:, 1] + mz * step[:, 2]
        leaving = d < 0
        t = jnp.where(leaving, a / jnp.where(leaving, -d, 1.0), jnp.inf)
        take = t < t_exit
        t_exit = jnp.where(take, t, t_exit)
        e_exit = jnp.where(take, e, e_exit)
        nxt = jnp.where(take, nxt_all[:, e], nxt)
    hit = alive & (nxt < 0) & (t_exit < 1.0 + _PAST_CENTRE)
    on = alive & (nxt >= 0) & (nxt != target) & (t_exit < 1.0)
    return hit, e_exit, jnp.where(on, nxt, -1)


def pair_pixels(pair, width: int, pixels: int):
    """The pixels of pair slots: ``(a, b, axis)``, each like ``pair`` (int32).

    Pair ``p < pixels`` joins pixel ``p`` and its right neighbour (axis 0); ``p >= pixels`` joins
    pixel ``p - pixels`` and the one below it (axis 1).
    """
    axis = (pair >= pixels).astype(jnp.int32)
    a = pair - axis * pixels
    return a, a + jnp.where(axis == 1, width, 1), axis


def front_is_a(tri_a, tri_b, depth_a, depth_b):
    """Whether pixel ``a`` of each pair holds the front surface (an empty pixel never does),
    from the two pixels' triangle ids and depths."""
    return (tri_a >= 0) & ((tri_b < 0) | (depth_a <= depth_b))


# Faces each lane crosses between refills (the refill's running sums and scatters are the
# step's fixed cost; 1, 2 and 3 measured alike on the bunny).
_ROUND = 3
# Screen tiles (pixels a side) that the silhouette edges' reach is marked in.
_TILE = 4
# How far from a silhouette edge's projection (in pixels) a pair's first pixel centre can be
# when its segment crosses the edge: one pixel step, _PAST_CENTRE beyond, and rounding.
_REACH = 1.0 + _PAST_CENTRE + 0.125


def near_silhouettes(onward, faces, screen, z, shape):
    """(H, W) bool: the pixels within reach of a silhouette edge's projection (conservative).

    A walk crosses a silhouette edge only between its pair's two centres, so a pair whose first
    pixel is further than ``_REACH`` from every silhouette edge's projection cannot blend.  The
    faces holding a silhouette edge (a few percent of a closed mesh's) are listed, and each marks
    the screen tiles its projected box (grown by the reach) overlaps, by a difference array and
    two running sums over the tiles.  Every pixel is marked where a silhouette face has a corner
    at or behind the eye plane (its projection is unbounded) or where more than 1/8 of the faces
    hold a silhouette edge (the list's size).

    Args:
        onward: (F, 3) from :func:`edge_planes`; faces: (F, 3).
        screen: (V, 2) the vertices' pixel coordinates; z: (V,) their camera-space depths.
        shape: ``(H, W)`` (static).
    """
    h, w = shape
    th, tw = -(-h // _TILE), -(-w // _TILE)
    n = faces.shape[0]
    sil = jnp.any(onward < 0, axis=1)
    listed = compact(sil, max(1, n // 8), n)
    ok = listed < n
    corners = faces[jnp.minimum(listed, n - 1)]  # (S, 3)
    xy = screen[corners]  # (S, 3, 2)
    # Tile bounds clipped as floats (a corner just in front of the eye projects far off
    # screen, beyond int32), then one tile outside the grid at most.
    top = jnp.array([tw, th], xy.dtype)
    lo = jnp.clip(jnp.floor((jnp.min(xy, 1) - (_REACH + 0.5)) / _TILE), 0, top).astype(jnp.int32)
    hi = jnp.clip(jnp.floor((jnp.max(xy, 1) + (_REACH - 0.5)) / _TILE), -1, top - 1)
    hi = hi.astype(jnp.int32)
    x0, y0, x1, y1 = lo[:, 0], lo[:, 1], hi[:, 0], hi[:, 1]
    seen = ok & (x0 <= x1) & (y0 <= y1)
    unbounded = jnp.sum(sil) > listed.shape[0]
    unbounded |= jnp.any(ok & jnp.any(z[corners] <= 0.0, axis=1))
    rows = jnp.concatenate([y0, y0, y1 + 1, y1 + 1])
    cols = jnp.concatenate([x0, x1 + 1, x0, x1 + 1])
    one = jnp.ones_like(x0)
    signs = jnp.concatenate([one, -one, -one, one])
    rows = jnp.where(jnp.tile(seen, 4), rows, th + 1)
    grid = jnp.zeros((th + 1, tw + 1), jnp.int32).at[rows, cols].add(signs, mode="drop")
    marked = running_sum(running_sum(grid, axis=0), axis=1)[:th, :tw] > 0
    marked = jnp.repeat(jnp.repeat(marked, _TILE, 0), _TILE, 1)[:h, :w]
    return marked | unbounded


def _candidates(tri, near):
    """(2 H W,) bool: the pairs whose pixels see different triangles, one of them covered,
    and whose first pixel is ``near`` a silhouette edge."""
    h, w = tri.shape
    right = jnp.pad(tri[:, 1:], ((0, 0), (0, 1)), constant_values=-1)
    below = jnp.pad(tri[1:], ((0, 1), (0, 0)), constant_values=-1)
    inside = (jnp.arange(w) < w - 1)[None, :], (jnp.arange(h) < h - 1)[:, None]
    masks = [
        ok & near & (tri != other) & ((tri >= 0) | (other >= 0))
        for ok, other in zip(inside, (right, below), strict=True)
    ]
    return jnp.concatenate([m.reshape(-1) for m in masks])


def _walk_start(job, pairs, tri, depth, rays, steps, width: int):
    """A walk's start: ``(face, target, ray, step)`` for jobs ``2 * slot + side``.

    Side 0 walks from the front pixel's triangle towards the other pixel, side 1 back from the
    other pixel's towards the front one.
    """
    pixels = tri.shape[0]
    a, b, axis = pair_pixels(pairs[job >> 1], width, pixels)
    ta, tb = tri[a], tri[b]
    from_a = front_is_a(ta, tb, depth[a], depth[b]) == ((job & 1) == 0)
    step = steps[axis]
    return (
        jnp.where(from_a, ta, tb),
        jnp.where(from_a, tb, ta),
        jnp.where(from_a[:, None], rays[a], rays[b]),
        jnp.where(from_a[:, None], step, -step),
    )


def find_outlines(normals, onward, near, tri, depth, rays, steps, *, background: bool, lanes: int):
    """Walks every candidate pair of one frame to the outline it crosses, in a pool of lanes.

    Args:
        normals, onward: (F, 9) and (F, 3) from :func:`edge_planes` (no gradients).
        near: (H, W) bool from :func:`near_silhouettes`: the pixels whose pairs are walked.
        tri: (H, W) int32 triangle ids (-1 empty); depth (H, W): they order each pair.
        rays: (H W, 3) pixel rays at z = 1; steps: (2, 3) the step from a pixel's ray to its
            right neighbour's and to the one below's (no gradients).
        background: also walk back from the other pixel where both are covered (static).
        lanes: the pool's width (static).

    Returns:
        :class:`OutlineHits`.
    """
    h, w = tri.shape
    pixels = h * w
    q = 2 * pixels
    tri_f, depth_f = tri.reshape(-1), depth.reshape(-1)
    candidate = _candidates(tri, near)
    pairs = compact(candidate, q, q)
    count = jnp.sum(candidate, dtype=jnp.int32)
    lanes = max(1, min(lanes, q))

    def start(job):
        return _walk_start(jnp.maximum(job, 0), pairs, tri_f, depth_f, rays, steps, w)

    def step(state):
        head, n_back, backs, hits, n_hits, job, cur, target, ray, stp, hops, face, edge = state
        # _ROUND faces for every lane; a walk that ends keeps its result until the round's end.
        found = jnp.full_like(cur, -1)
        found_edge = jnp.zeros_like(cur)
        done = jnp.zeros(cur.shape, bool)
        for _ in range(_ROUND):
            safe = jnp.maximum(cur, 0)
            hit, exit_edge, nxt = _hop(normals[safe], onward[safe], cur, target, ray, stp)
            hops = hops + 1
            ends = (cur >= 0) & ((nxt < 0) | (hops > MAX_HOPS))
            found = jnp.where(ends & hit, cur, found)
            found_edge = jnp.where(ends, exit_edge, found_edge)
            done = done | ends
            cur = jnp.where(ends, -1, nxt)
        slot, side = job >> 1, job & 1
        at = jnp.where(done, side * q + slot, 2 * q)
        face = face.at[at].set(found, mode="drop")
        edge = edge.at[at].set(found_edge, mode="drop")
        listed = done & (found >= 0) & (side == 0)
        queue = listed & (target >= 0) if background else jnp.zeros_like(listed)
        # Lanes without a walk take the next ones: front walks (slots below `count`), then
        # the back walks queued so far (this round's included).
        free = cur < 0
        rank = running_sum(jnp.stack([listed, queue, free]).astype(jnp.int32), axis=1) - 1
        hits = hits.at[jnp.where(listed, n_hits + rank[0], q)].set(slot, mode="drop")
        backs = backs.at[jnp.where(queue, n_back + rank[1], q)].set(slot, mode="drop")
        n_hits = n_hits + jnp.sum(listed, dtype=jnp.int32)
        n_back = n_back + jnp.sum(queue, dtype=jnp.int32)
        u = head + rank[2]
        take = free & (u < count + n_back)
        queued = jnp.where(u < count, 2 * u, 2 * backs[jnp.clip(u - count, 0, q - 1)] + 1)
        f0, t0, r0, s0 = start(jnp.where(take, queued, 0))
        job = jnp.where(take, queued, jnp.where(free, -1, job))
        cur, target = jnp.where(take, f0, cur), jnp.where(take, t0, target)
        ray, stp = jnp.where(take[:, None], r0, ray), jnp.where(take[:, None], s0, stp)
        hops = jnp.where(take, 0, hops)
        head = jnp.minimum(head + jnp.sum(free, dtype=jnp.int32), count + n_back)
        return head, n_back, backs, hits, n_hits, job, cur, target, ray, stp, hops, face, edge

    def busy(state):
        head, n_back, cur = state[0], state[1], state[6]
        return (head < count + n_back) | jnp.any(cur >= 0)

    zero = jnp.zeros((), jnp.int32)
    none = jnp.full((lanes,), -1, jnp.int32)
    vec = jnp.zeros((lanes, 3), rays.dtype)
    slots = jnp.full((q,), q, jnp.int32)
    unset = jnp.full((2 * q,), -1, jnp.int32)
    init = (zero, zero, slots, slots, zero, none, none, none, vec, vec, none + 1, unset, unset)
    state = jax.lax.while_loop(busy, step, init)
    return OutlineHits(pairs, state[11].reshape(2, q), state[12].reshape(2, q), state[3], state[4])
