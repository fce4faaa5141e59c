"""Differentiable silhouettes: analytic antialiasing of a rasterized image.

A z-buffer image is piecewise constant in the vertex positions at silhouettes: moving an outline
edge by less than a pixel changes no pixel until a pixel centre is crossed, so the gradient of the
image with respect to the geometry is zero there.  This pass, after nvdiffrast's antialias
operation (Laine et al. 2020, "Modular Primitives for High-Performance Differentiable Rendering",
ACM TOG 39(6), Sec. 3.4), blends each pair of neighbouring pixels that see different triangles by
where the outline of the front surface crosses the segment between the two pixel centres.  The
result is continuous in the vertices and the camera as outlines cross pixel centres (parts
thinner than a pixel aside, see below), so the derivatives of its sums (covered area, centroid,
an image loss) are those of the covered area, not only of the blend between crossings.

**The pair blend.**  For pixel centres ``F`` (covered by the front surface) and ``O`` (the other
pixel), with the outline crossing the segment at ``t`` in ``[0, 1]`` (``t = 0`` at ``F``):

* ``t > 1/2``: the surface reaches past the midpoint, ``O`` takes ``t - 1/2`` of ``F``'s colour;
* ``t < 1/2``: the surface stops short of it, ``F`` takes ``1/2 - t`` of ``O``'s colour.

Along one row of a coverage image this makes the row's sum the covered length of its centre
line exactly: the covered centres count 1 each, and the end pair adds ``t - 1/2``, the distance
from the last covered pixel's boundary to the crossing.  It is continuous as the outline crosses
a pixel centre: at ``t -> 1``, ``O`` holds ``1/2`` of ``F``; once the z-buffer flips ``O`` to
covered, the pair on ``O``'s far side sees the crossing at ``t -> 0`` from ``O``, which keeps
``1 - 1/2``.

**Two axes, one edge.**  An outline edge crosses rows and columns alike, and the row blend
alone, like the column blend alone, already makes up the jump of a pixel that flips.  Both at
full weight would take it back twice (the image jumps the other way) and double the area's
derivative.  So each edge's blends are weighted: ``w_x = g_x^2 / (g_x^2 + g_y^2)`` on horizontal
pairs and ``w_y = 1 - w_x`` on vertical pairs, where ``(g_x, g_y)`` is the gradient of the edge's
line in pixels (``w_x = 1`` for a vertical edge).  Because ``w_x + w_y = 1``:

* the image is continuous where an edge crosses a pixel centre: the line through that centre
  crosses all four of its pairs at the centre, so their blends jump by ``-w_x`` and ``-w_y``
  against the raw ``+1``;
* moving an edge of length ``L`` by ``d`` along its normal changes its row blends by ``d L`` and
  its column blends by ``d L``, so the area changes by ``d L``, its true change.

A weight falls to zero (quadratically) along the axis the edge runs along, where the crossing on
that axis is ill-conditioned.  nvdiffrast gives each edge to one axis (the one more across it);
that jumps by up to ``1/2`` per pair where an edge turns past 45 degrees or two outline edges on
either side of 45 degrees meet.  Here the residual jumps are where the crossing passes a
silhouette vertex, ``|t - 1/2| |w(e_1) - w(e_2)|``, small where the outline turns little.

**Finding the crossing.**  The crossing is on the front surface's outline, which need not be an
edge of the triangle seen at ``F``: beside a silhouette the surface is seen nearly edge-on and
its faces are often thinner than a pixel, so the segment from ``F``'s centre leaves its triangle
through an interior edge.  The segment is followed across interior edges into the adjacent face
(the faces from :func:`silhouette_edges`), up to ``MAX_HOPS`` faces, until it crosses a silhouette
edge (the pair blends) or reaches ``O``'s centre (no outline between them).  The walk is discrete
and carries no gradient; the crossing is then computed from the edge it found, differentiably.

**Gaps and thin parts.**  Where both pixels of a pair are covered, by a near and a far
surface with a gap between their outlines, the gap shows what is behind both, whose colour no
pixel holds: given a ``background`` colour, both outlines blend towards it (for a coverage image
it is 0).  A part thinner than a pixel lying between two empty pixel centres (a tip, a thin
limb seen from the side) is in no pixel: it appears, with a jump of its width, when it reaches
a centre.

Projected edges are handled in camera space: the edge ``(P, Q)`` and the eye span the plane with
normal ``P x Q``; a pixel ray ``r`` is on the side ``sign((P x Q) . r)``, and the crossing along
the segment from ray ``r_F`` to ``r_O`` is linear in that dot product.  This stays exact and
finite for edges with an endpoint behind the camera (no near-plane clipping is needed), and an
edge through the eye simply has no crossing.

An edge of a face is a *silhouette* edge when it is a boundary edge (one face) or when the face
on its other side folds back: its far vertex lies on the same side of the edge's eye plane as the
face's own third vertex (the two faces face opposite ways with respect to the camera).  Only
silhouette edges blend; the shared edges of a continuous surface are left alone, and so are
outlines that are not mesh edges: where the near or far plane cuts a triangle, and where two
surfaces intersect.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import (
    Camera,
    focal_lengths,
    screen_to_camera,
    validate_camera,
    world_to_camera,
)
from jaxgfx._src.checks import require_finite, require_indices
from jaxgfx._src.raster import RasterOutput, validate_mesh

__all__ = ["silhouette_edges", "analytic_antialias"]


def silhouette_edges(faces, vertices=None) -> np.ndarray:
    """Edge topology for :func:`analytic_antialias`: the same edge seen from the face across.

    Computed once on the host for a mesh (it depends on the faces, and on which vertices share a
    position, not on the pose or the camera).  Edge ``e`` of face ``f`` runs from
    ``faces[f, e]`` to ``faces[f, (e + 1) % 3]``.

    Args:
        faces: (F, 3) integer vertex indices (concrete, not traced).
        vertices: optional (V, 3) positions (concrete).  Vertices at exactly the same position
            are then one vertex for the topology: meshes split their vertices where normals or
            texture coordinates differ (a flat-shaded glTF mesh has three vertices of its own per
            face), and without welding every such edge would be a boundary, that is, an
            outline.  Give a pose where split vertices coincide (the bind pose).

    Returns:
        (F, 3) int32: for edge ``e`` of face ``f``, the same edge in the other face holding it
        as ``3 * g + k`` (edge ``k`` of face ``g``), or -1 when the edge is a boundary edge or is
        shared by more than two faces (a non-manifold fin is drawn as an outline from every
        side).

    Raises:
        TypeError: ``faces`` or ``vertices`` is traced, or ``faces`` is not integer.
        ValueError: ``faces`` is not (F, 3), or ``vertices`` is not a (V, 3) array that
            ``faces`` indexes.
    """
    if isinstance(faces, jax.core.Tracer) or isinstance(vertices, jax.core.Tracer):
        raise TypeError(
            "faces and vertices must be concrete to build silhouette_edges (call it outside jit)"
        )
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[-1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise TypeError(f"faces must be integer indices, got {f.dtype}")
    n = f.shape[0]
    out = np.full((n, 3), -1, np.int32)
    if n == 0:
        return out
    a = f.astype(np.int64)
    if vertices is not None:
        v = np.asarray(vertices)
        if v.ndim != 2 or v.shape[-1] != 3:
            raise ValueError(f"vertices must have shape (V, 3), got {v.shape}")
        if a.min() < 0 or a.max() >= v.shape[0]:
            raise ValueError(f"faces must index the {v.shape[0]} vertices")
        # One id per distinct position (+ 0.0 makes -0.0 equal to 0.0 bit for bit).
        a = np.unique(v + 0.0, axis=0, return_inverse=True)[1].reshape(-1)[a]
    b = np.roll(a, -1, axis=1)  # edge e: faces[:, e] -> faces[:, e + 1]
    lo, hi = np.minimum(a, b).ravel(), np.maximum(a, b).ravel()
    key = lo * (int(a.max()) + 1) + hi
    order = np.argsort(key, kind="stable")
    sk = key[order]
    start = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]])
    count = np.diff(np.r_[start, sk.size])
    # Manifold edges: exactly two face-edges with the same key, adjacent after sorting.
    pair = start[count == 2]
    e0, e1 = order[pair], order[pair + 1]
    # A face holding one edge twice (a repeated vertex) has no neighbour across it.
    ok = (e0 // 3 != e1 // 3) & (lo[e0] != hi[e0])
    flat = out.reshape(-1)
    flat[e0[ok]] = e1[ok]
    flat[e1[ok]] = e0[ok]
    return out


MAX_HOPS = 16
"""Faces the walk from a pixel's triangle towards its neighbour's centre may cross.

Beside an outline the surface is seen nearly edge-on, so several thin faces can lie between two
pixel centres; a pair whose outline is further than this many faces away is left unblended.
"""

# Crossings this far (in pixel steps) past the other pixel's centre still blend, clamped to it:
# the rasterizer's coverage test and the plane test here round differently.
_PAST_CENTRE = 1.0 / 16.0


def _edge_planes(p_cam, faces, across):
    """Per face and edge: the inward normal of the edge's eye plane, and where the walk goes next.

    Args:
        p_cam: (V, 3) camera-space vertices; faces (F, 3); across (F, 3) from
            :func:`silhouette_edges`.

    Returns:
        ``(normal (F, 3 edges, 3), onward (F, 3) int32)``.  The normal is oriented so that the
        face's own third vertex has a positive dot product, and is zero for a face seen edge-on
        (then no ray is inside).  ``onward`` is the face across the edge, or -1 where the edge
        is a silhouette edge (boundary, or the face across folds back).
    """
    pts = p_cam[faces]  # (F, 3 corners, 3)
    other = jnp.maximum(across, 0)
    # The far vertex of the face across: the corner after the shared edge's end in that face.
    far = faces[other // 3, (other % 3 + 2) % 3]  # (F, 3)
    normals, onward = [], []
    for e in range(3):
        p, q, k = pts[:, e], pts[:, (e + 1) % 3], pts[:, (e + 2) % 3]
        n = jnp.cross(p, q)  # normal of the plane through the eye and the edge
        m = jnp.sign(jnp.sum(n * k, -1))[:, None] * n
        folds = jnp.sum(m * p_cam[far[:, e]], -1) >= 0
        normals.append(m)
        onward.append(jnp.where((across[:, e] < 0) | folds, -1, other[:, e] // 3))
    return jnp.stack(normals, 1), jnp.stack(onward, 1).astype(jnp.int32)


def _hop(nrm, nxt_all, face, target, ray, step):
    """One step of the walk: where the segment leaves ``face``, and what lies beyond.

    Args:
        nrm: (N, 9) the edge-plane normals of ``face``; nxt_all: (N, 3) its walk table row
            (:func:`_edge_planes`).
        face: (N,) the current faces, -1 for finished walks.
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


def _walk_to_outline(normals, onward, face, face_n, face_on, target, ray, step):
    """The silhouette edge the segment from a pixel centre to its neighbour's crosses first.

    Follows the segment ``ray + t step`` from ``face`` across interior edges into the faces
    beyond, up to :data:`MAX_HOPS` faces: in each face it leaves through the edge it crosses
    outwards first (faces are convex), at the smallest ``t`` beyond its entry.  Discrete: call
    it on values without gradients.

    Args:
        normals: (F, 3, 3) :func:`_edge_planes` normals; onward: (F, 3) its walk table.
        face: (N,) the starting face (the front pixel's triangle), -1 for no walk.
        face_n, face_on: (N, 9) and (N, 3), ``normals`` and ``onward`` of ``face`` (gathered
            once per pixel by the caller).
        target: (N,) the other pixel's triangle (-1: none).
        ray, step: (N, 3) the front pixel's ray and the step to the other pixel's.

    Returns:
        ``(face, edge, first)``, each (N,): the face holding the silhouette edge crossed (-1
        where the segment reaches the other centre first, no outline between them, or the walk
        gave up), the edge's index in it, and whether that face is the starting one.
    """
    flat_n = normals.reshape(normals.shape[0], 9)
    face = face.astype(jnp.int32)
    n = face.shape[0]
    # The first face, for every pair at once: most walks end in it.
    hit, hit_edge, cur = _hop(face_n, face_on, face, target, ray, step)
    first = hit
    hit_face = jnp.where(hit, face, -1)
    # The rest (segments across faces thinner than a pixel, beside outlines) a chunk of walks
    # at a time, each to its end.  While loops: they carry no gradient.
    size = max(1, min(n, n // 16))

    def chunk(state):
        cur, hit_face, hit_edge = state
        # The first `size` walks still going; index n pads the chunk and reads as a done walk.
        idx = jnp.nonzero(cur >= 0, size=size, fill_value=n)[0]
        at = jnp.minimum(idx, n - 1)
        tgt, r, st = target[at], ray[at], step[at]

        def hop(inner):
            k, c, hf, he = inner
            safe = jnp.maximum(c, 0)
            h, e, c_next = _hop(flat_n[safe], onward[safe], c, tgt, r, st)
            return k + 1, c_next, jnp.where(h, c, hf), jnp.where(h, e, he)

        def walking(inner):
            return (inner[0] < MAX_HOPS) & jnp.any(inner[1] >= 0)

        none = jnp.full((size,), -1, jnp.int32)
        start = (jnp.zeros((), jnp.int32), jnp.where(idx < n, cur[at], -1), none, none + 1)
        _, _, hf, he = jax.lax.while_loop(walking, hop, start)
        # Every walk of the chunk is over: an outline, the other centre, or MAX_HOPS faces.
        return (
            cur.at[idx].set(-1, mode="drop"),
            hit_face.at[idx].set(hf, mode="drop"),
            hit_edge.at[idx].set(he, mode="drop"),
        )

    _, hit_face, hit_edge = jax.lax.while_loop(
        lambda state: jnp.any(state[0] >= 0), chunk, (cur, hit_face, hit_edge)
    )
    return hit_face, hit_edge, first


def _outline_crossing(normals, onward, focal, face, face_n, face_on, target, ray, direction, axis):
    """Where each segment first crosses its surface's outline, and the blend's weight there.

    Args:
        normals, onward: :func:`_edge_planes` (normals with gradients).
        focal: ``(fx, fy)`` focal lengths in pixels.
        face: (N,) the triangle at the segment's start (-1: none); face_n (N, 9) and face_on
            (N, 3): its normals (with gradients) and walk table row.
        target: (N,) the triangle at the other end (-1: none).
        ray, direction: (N, 3) the start pixel's ray and the step to the other pixel's.
        axis: 0 for horizontal pairs, 1 for vertical pairs.

    Returns:
        ``(t, weight)``, each (N,): the crossing in [0, 1] from the start (1 where none) and the
        weight of its blend along ``axis`` (0 where no outline is crossed).
    """
    sg = jax.lax.stop_gradient
    hit, edge, first = _walk_to_outline(
        sg(normals), onward, face, sg(face_n), face_on, target, sg(ray), sg(direction)
    )
    # The crossed edge's plane, with gradients: from the starting face's row where the walk
    # ended in it, else gathered.  Those few are gathered with gradients as a chunk of
    # static size (a gather over all pairs would cost a scatter over all pairs in reverse
    # mode); beyond the chunk, the plane carries no gradient.
    own = face_n[:, 0:3]
    for e in (1, 2):
        own = jnp.where((edge == e)[:, None], face_n[:, 3 * e : 3 * e + 3], own)
    late_face = jnp.maximum(hit, 0)
    n_late = sg(normals)[late_face, edge]
    count = face.shape[0]
    idx = jnp.nonzero((hit >= 0) & ~first, size=max(1, count // 32), fill_value=count)[0]
    at = jnp.minimum(idx, count - 1)
    n_late = n_late.at[idx].set(normals[late_face[at], edge[at]], mode="drop")
    n = jnp.where(first[:, None], own, n_late)
    a = jnp.sum(n * ray, -1)
    d = jnp.sum(n * direction, -1)
    ok = (hit >= 0) & (d < 0)
    t = jnp.clip(jnp.where(ok, a / jnp.where(ok, -d, 1.0), 1.0), 0.0, 1.0)
    # The edge's line in pixels: its plane's normal scaled by the pixel steps along x and y.
    gx, gy = n[:, 0] / focal[0], n[:, 1] / focal[1]
    g2 = gx * gx + gy * gy
    along = gx * gx if axis == 0 else gy * gy
    weight = jnp.where(ok, along / jnp.where(ok, g2, 1.0), 0.0)
    return t, weight


def _blend(t, weight, col_near, col_far):
    """One outline's blend: the pixel it starts from and the other, each (N, C).

    The surface covers the segment from the near pixel's centre to ``t``; ``col_far`` is seen
    beyond.  Returns the changes of the near and the far pixel.
    """
    w_far = (weight * jnp.maximum(t - 0.5, 0.0))[:, None]
    w_near = (weight * jnp.maximum(0.5 - t, 0.0))[:, None]
    return w_near * (col_far - col_near), w_far * (col_near - col_far)


def _pair_deltas(normals, onward, focal, tri, px_n, px_on, depth, ray, col, step, axis, background):
    """Colour changes of the two pixels of every pair (a, b) along one axis (N pairs).

    Args:
        normals, onward: :func:`_edge_planes`; focal: ``(fx, fy)``.
        tri, px_n, px_on, depth, ray, col: pairs of (N,) triangle ids (-1 empty), (N, 9) and
            (N, 3) their rows of ``normals`` and ``onward``, (N,) depths, (N, 3) rays and (N, C)
            colours, for pixel a and pixel b.
        step: (3,) from a's ray to b's; axis: 0 horizontal, 1 vertical.
        background: (C,) colour behind every surface, or None.

    Returns:
        ``(delta_a, delta_b)``, each (N, C).
    """
    (tri_a, tri_b), (depth_a, depth_b), (ray_a, ray_b), (col_a, col_b) = tri, depth, ray, col
    (n_a, n_b), (on_a, on_b) = px_n, px_on
    # The front surface is the nearer one; an empty pixel is never in front.
    a_front = (tri_a >= 0) & ((tri_b < 0) | (depth_a <= depth_b))
    active = (tri_a != tri_b) & ((tri_a >= 0) | (tri_b >= 0))
    front = jnp.where(active, jnp.where(a_front, tri_a, tri_b), -1)
    back = jnp.where(active, jnp.where(a_front, tri_b, tri_a), -1)
    ray_f = jnp.where(a_front[:, None], ray_a, ray_b)
    ray_o = jnp.where(a_front[:, None], ray_b, ray_a)
    dir_f = jnp.where(a_front[:, None], step, -step)
    col_f = jnp.where(a_front[:, None], col_a, col_b)
    col_o = jnp.where(a_front[:, None], col_b, col_a)
    n = tri_a.shape[0]
    n_f, n_o = jnp.where(a_front[:, None], n_a, n_b), jnp.where(a_front[:, None], n_b, n_a)
    on_f, on_o = jnp.where(a_front[:, None], on_a, on_b), jnp.where(a_front[:, None], on_b, on_a)
    t_f, w_f = _outline_crossing(normals, onward, focal, front, n_f, on_f, back, ray_f, dir_f, axis)
    if background is None:
        d_f, d_o = _blend(t_f, w_f, col_f, col_o)
    else:
        # The back surface's outline, where the front's is crossed and both pixels are covered:
        # if it shows beyond the front's, a gap between them shows the background.  Those
        # pairs (outlines over a surface) are few: they are walked as a chunk of static size,
        # and beyond it blend as without a background.
        size = max(1, n // 16)
        idx = jnp.nonzero((w_f > 0) & (back >= 0), size=size, fill_value=n)[0]
        at = jnp.minimum(idx, n - 1)
        t_s, w_s = _outline_crossing(
            normals, onward, focal, jnp.where(idx < n, back[at], -1), n_o[at], on_o[at],
            front[at], ray_o[at], -dir_f[at], axis,
        )  # fmt: skip
        t_o = jnp.ones_like(t_f).at[idx].set(t_s, mode="drop")
        w_o = jnp.zeros_like(w_f).at[idx].set(w_s, mode="drop")
        gap = (w_f > 0) & (w_o > 0) & (t_f + t_o < 1.0)
        bg = jnp.broadcast_to(background, col_f.shape)
        d_f, d_o = _blend(t_f, w_f, col_f, jnp.where(gap[:, None], bg, col_o))
        g_o, g_f = _blend(t_o, jnp.where(gap, w_o, 0.0), col_o, bg)
        d_f, d_o = d_f + g_f, d_o + g_o
    delta_a = jnp.where(a_front[:, None], d_f, d_o)
    delta_b = jnp.where(a_front[:, None], d_o, d_f)
    return delta_a, delta_b


def analytic_antialias(
    cam: Camera,
    vertices: jax.Array,
    faces: jax.Array,
    raster_out: RasterOutput,
    color: jax.Array | None = None,
    *,
    edges: jax.Array | None = None,
    background: jax.Array | float | None = None,
) -> jax.Array:
    """Blends pixels across silhouette edges, so the image is continuous in the geometry.

    Pure and traceable: jit it, ``vmap`` it over cameras or poses (one image per call).
    Gradients flow to ``vertices`` and the camera through where outlines cross between pixel
    centres, and to ``color`` (e.g. through :func:`jaxgfx.raster.interpolate`).  The covered
    area of a coverage image follows the outline as it moves across pixel centres, so sums of
    the image (area, centroid, a loss) have derivatives of the right size over steps of a pixel
    and more (module docstring).

    Args:
        cam: the camera ``raster_out`` was rendered with.
        vertices: (V, 3) world positions, the ones rasterized.
        faces: (F, 3) int vertex indices.
        raster_out: :class:`jaxgfx.raster.RasterOutput` of
            ``rasterize(cam, vertices, faces, ...)``; its ``tri_id`` and
            ``depth`` decide which pixels pair up and which triangle is in front.
        color: (H, W, C) image to antialias (shaded, composited over a
            background, ...); default ``raster_out.color``.
        edges: (F, 3) int32 from :func:`silhouette_edges` (precompute it once
            per mesh, with the bind-pose ``vertices`` when the mesh splits vertices
            at seams); default: ``silhouette_edges(faces)``, computed here on the
            host, which needs concrete ``faces``.
        background: optional colour seen behind every surface, () or (C,) (0 for a coverage
            image).  With it, where the two pixels of a pair see two surfaces with a gap between
            them narrower than a pixel (two legs side by side), both outlines blend towards
            it; without it (as in nvdiffrast), only the front surface's outline blends, towards
            the other pixel's colour.

    Returns:
        (H, W, C) antialiased image; pixels away from silhouettes are unchanged.

    Raises:
        ValueError: bad shapes or values of concrete inputs (checked before tracing), and
            inside :func:`~jaxgfx.checks.checked` bad traced values too (those of
            :func:`jaxgfx.raster.rasterize`; face ids, edges, colour, background).
        TypeError: bad dtypes or types of concrete inputs (checked before tracing).

    References:
        S. Laine, J. Hellsten, T. Karras, Y. Seol, J. Lehtinen, T. Aila,
        "Modular Primitives for High-Performance Differentiable Rendering",
        ACM TOG 39(6), 2020, Sec. 3.4 (analytic antialiasing).
    """
    validate_camera(cam, where="analytic_antialias")
    validate_mesh(vertices, faces, where="analytic_antialias")
    topo = silhouette_edges(faces) if edges is None else edges
    image = raster_out.color if color is None else color
    h, w = cam.height, cam.width
    for name, arr, shape in (
        ("raster_out.tri_id", raster_out.tri_id, (h, w)),
        ("raster_out.depth", raster_out.depth, (h, w)),
        ("edges", topo, (np.shape(faces)[0], 3)),
    ):
        if tuple(np.shape(arr)) != shape:
            raise ValueError(f"{name} must have shape {shape}, got {tuple(np.shape(arr))}")
    if np.ndim(image) != 3 or tuple(np.shape(image)[:2]) != (h, w):
        raise ValueError(f"color must have shape ({h}, {w}, C), got {tuple(np.shape(image))}")
    vertices = jnp.asarray(vertices, jnp.float32)
    faces = jnp.asarray(faces, jnp.int32)
    across = jnp.asarray(topo, jnp.int32)
    color = jnp.asarray(image, jnp.float32)
    cols = color.shape[-1]
    if background is not None and np.shape(background) not in ((), (cols,)):
        raise ValueError(
            f"background must be a scalar or have shape ({cols},), got {np.shape(background)}"
        )
    _require_inputs(raster_out, image, topo, background, np.shape(faces)[0])
    if faces.shape[0] == 0:
        return color
    bg = (
        None
        if background is None
        else jnp.broadcast_to(jnp.asarray(background, jnp.float32), (cols,))
    )
    return _compiled_antialias(
        cam, vertices, faces, across, raster_out.tri_id, raster_out.depth, color, bg
    )


@jax.jit
def _compiled_antialias(cam, vertices, faces, across, tri, depth, color, bg):
    """:func:`analytic_antialias` of checked arrays, as one compiled program.

    An eager call runs it compiled once per shapes; op by op, its outline walks would
    compile again at every call (seconds each) and round apart from the jitted pass.
    Under the caller's ``jit`` (or ``vmap``, ``grad``) the call is inlined.
    """
    h, w = cam.height, cam.width
    cols = color.shape[-1]
    p_cam = world_to_camera(cam, vertices)
    fx, fy = focal_lengths(cam)
    xs, ys = screen_to_camera(
        cam, jnp.arange(w, dtype=jnp.float32) + 0.5, jnp.arange(h, dtype=jnp.float32) + 0.5
    )
    gx, gy = jnp.meshgrid(xs, ys)
    rays = jnp.stack([gx, gy, jnp.ones_like(gx)], axis=-1)  # (H, W, 3), z = 1
    # Depth only orders the pair; the blend's gradient comes from the edge.
    depth = jax.lax.stop_gradient(depth)
    normals, onward = _edge_planes(p_cam, faces, across)
    # Each pixel's triangle's planes and walk table, gathered once for its four pairs.
    safe_tri = jnp.maximum(tri, 0)
    px_n = normals.reshape(-1, 9)[safe_tri]  # (H, W, 9), with gradients
    px_on = onward[safe_tri]  # (H, W, 3)
    zero = jnp.zeros((), rays.dtype)
    # Horizontal pairs (x, x + 1): the next ray is 1 / fx further along camera x; vertical pairs
    # (y, y + 1): 1 / fy further down, i.e. along -y.
    horizontal = (np.s_[:, :-1], np.s_[:, 1:], jnp.stack([1.0 / fx, zero, zero]))
    vertical = (np.s_[:-1], np.s_[1:], jnp.stack([zero, -1.0 / fy, zero]))
    out = color
    for axis, (a, b, step) in enumerate((horizontal, vertical)):
        pair_shape = (*tri[a].shape, cols)
        da, db = _pair_deltas(
            normals, onward, (fx, fy), _pairs(tri, a, b), _pairs(px_n, a, b),
            _pairs(px_on, a, b), _pairs(depth, a, b), _pairs(rays, a, b), _pairs(color, a, b),
            step, axis, bg,
        )  # fmt: skip
        # Back to the frame: a's changes miss the last column (row), b's the first.
        last, first = [(0, 0)] * 3, [(0, 0)] * 3
        last[1 - axis], first[1 - axis] = (0, 1), (1, 0)
        out = out + jnp.pad(da.reshape(pair_shape), last) + jnp.pad(db.reshape(pair_shape), first)
    return out


def _require_inputs(raster_out, color, edges, background, n_faces: int) -> None:
    """Under :func:`~jaxgfx.checks.checked`: the traced values a wrong blend would come from.

    A face id beyond the faces or an edge beyond the edge table is clamped by the gathers,
    so a pixel would blend along another face's outline; a NaN colour spreads to its pair.
    """
    where = "analytic_antialias"
    require_indices(
        "raster_out.tri_id", raster_out.tri_id, n_faces, "faces", where, allow_minus_one=True
    )
    require_indices("edges", edges, 3 * n_faces, "face edges", where, allow_minus_one=True)
    require_finite("color", color, where)
    if background is not None:
        require_finite("background", background, where)


def _pairs(image, a, b):
    """The pixels a and b of every pair, as two flat arrays (N, ...)."""
    tail = image.shape[2:]
    return image[a].reshape(-1, *tail), image[b].reshape(-1, *tail)
