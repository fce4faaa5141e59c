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

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import (
    Camera,
    camera_to_screen,
    focal_lengths,
    screen_to_camera,
    validate_camera,
    world_to_camera,
)
from jaxgfx._src.checks import require_finite, require_indices
from jaxgfx._src.frames import per_frame
from jaxgfx._src.outline_walk import (
    edge_plane,
    edge_planes,
    find_outlines,
    front_is_a,
    near_silhouettes,
    pair_pixels,
)
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


# The walk finds the crossed edge; the blend (with gradients) is worked out per listed pair, as
# many as this fraction of the frame's pair slots (2 H W) at once: the first ones with their
# gradients, any beyond them (only on frames where outlines fill more than 1/32 of the pair
# slots) a block at a time, for the image alone.
_LISTED_SHARE = 32
# The walk pool's width, as a fraction of the pair slots (at least _MIN_LANES lanes).
_LANE_SHARE = 64
_MIN_LANES = 256


def _crossing(plane, ray, direction, found, axis, focal):
    """Where the segment ``ray + t direction`` crosses an edge's plane, and the blend's weight.

    Args:
        plane: (N, 3) the edge's eye-plane normal; ray, direction: (N, 3).
        found: (N,) whether the walk crossed the edge (else no blend).
        axis: (N,) 0 for horizontal pairs, 1 for vertical pairs; focal: ``(fx, fy)``.

    Returns:
        ``(t, weight)``, each (N,): the crossing in [0, 1] from the start (1 where none) and
        the weight of its blend along the pair's axis (0 where no outline is crossed).
    """
    a = jnp.sum(plane * ray, -1)
    d = jnp.sum(plane * direction, -1)
    ok = found & (d < 0)
    t = jnp.clip(jnp.where(ok, a / jnp.where(ok, -d, 1.0), 1.0), 0.0, 1.0)
    # The edge's line in pixels: its plane's normal scaled by the pixel steps along x and y.
    gx, gy = plane[:, 0] / focal[0], plane[:, 1] / focal[1]
    g2 = gx * gx + gy * gy
    along = jnp.where(axis == 0, gx * gx, gy * gy)
    return t, jnp.where(ok, along / jnp.where(ok, g2, 1.0), 0.0)


def _blend(t, weight, col_near, col_far):
    """One outline's blend: the pixel it starts from and the other, each (N, C).

    The surface covers the segment from the near pixel's centre to ``t``; ``col_far`` is seen
    beyond.  Returns the changes of the near and the far pixel.
    """
    w_far = (weight * jnp.maximum(t - 0.5, 0.0))[:, None]
    w_near = (weight * jnp.maximum(0.5 - t, 0.0))[:, None]
    return w_near * (col_far - col_near), w_far * (col_near - col_far)


def _outline_deltas(found, slots, frame, color, background):
    """The colour changes of the pairs in ``slots`` of ``found.hits``, and their pixels.

    Args:
        found: :class:`~jaxgfx._src.outline_walk.OutlineHits` of the frame.
        slots: (N,) entries of ``found.hits`` (``Q`` pads).
        frame: ``(p_cam, faces, tri, depth, xs, ys, steps, focal)``: camera-space vertices
            (V, 3), faces, flat triangle ids and depths (H W,), the pixel centres' camera x
            (W,) and y (H,) at z = 1, the (2, 3) pixel steps and ``(fx, fy)``.
        color: (H W, C) the image; background: (C,) or None.

    Returns:
        ``(pixels (2 N,), deltas (2 N, C))``: pixel ``H W`` (out of range) for padding.
    """
    p_cam, faces, tri, depth, xs, ys, steps, focal = frame
    pixels, width = tri.shape[0], xs.shape[0]
    q = found.pairs.shape[0]
    listed = slots < q
    slot = jnp.minimum(slots, q - 1)
    a, b, axis = pair_pixels(found.pairs[slot], width, pixels)
    a_front = front_is_a(tri[a], tri[b], depth[a], depth[b])
    near, far = jnp.where(a_front, a, b), jnp.where(a_front, b, a)

    def ray(px):
        return jnp.stack([xs[px % width], ys[px // width], jnp.ones(px.shape, xs.dtype)], -1)

    step = jnp.where(a_front[:, None], steps[axis], -steps[axis])
    plane = edge_plane(p_cam, faces, found.face[0, slot], found.edge[0, slot])
    t_f, w_f = _crossing(plane, ray(near), step, listed, axis, focal)
    col_f, col_o = color[near], color[far]
    if background is None:
        d_f, d_o = _blend(t_f, w_f, col_f, col_o)
    else:
        # The back surface's outline, where both pixels are covered: if it shows beyond the
        # front's, a gap between them shows the background.
        back = found.face[1, slot]
        plane_o = edge_plane(p_cam, faces, back, found.edge[1, slot])
        t_o, w_o = _crossing(plane_o, ray(far), -step, listed & (back >= 0), axis, focal)
        gap = (w_f > 0) & (w_o > 0) & (t_f + t_o < 1.0)
        bg = jnp.broadcast_to(background, col_f.shape)
        d_f, d_o = _blend(t_f, w_f, col_f, jnp.where(gap[:, None], bg, col_o))
        g_o, g_f = _blend(t_o, jnp.where(gap, w_o, 0.0), col_o, bg)
        d_f, d_o = d_f + g_f, d_o + g_o
    at = jnp.concatenate([jnp.where(listed, near, pixels), jnp.where(listed, far, pixels)])
    return at, jnp.concatenate([d_f, d_o])


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

    Its work follows the outline, not the frame: only the pairs near a silhouette edge whose
    pixels see different triangles are walked (a pool of walks fed from a compacted queue),
    and only the pairs that cross an outline are blended.  Gradients flow through the first
    ``2 H W / 32`` such pairs of a frame (12,288 at 512x384; a 69 k-triangle bunny filling a
    third of it has about 2,000); pairs beyond them, where outlines fill more of the frame,
    still blend, without gradients.

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


@functools.cache
def _walks_kernel(background: bool, lanes: int):
    """:func:`~jaxgfx._src.outline_walk.find_outlines` of one frame, batched frame by frame on
    the CPU (its pool runs each frame's own steps, on cache-sized buffers) and vectorized
    elsewhere (:func:`~jaxgfx._src.frames.per_frame`); built once per configuration."""
    return per_frame(functools.partial(find_outlines, background=background, lanes=lanes))


def _walk_frame(cam, vertices, faces, across, tri, depth, *, background: bool, cull: bool = True):
    """The frame's rays and planes, and the walks of its candidate pairs.

    Args:
        cam, vertices, faces, across, tri, depth: as :func:`_compiled_antialias`.
        background: walk back from the other pixel too (static).
        cull: walk only the pairs near a silhouette edge (static; ``False`` walks every pair
            whose pixels see different triangles, the reference the tests hold it to).

    Returns:
        ``(found, frame)``: :class:`~jaxgfx._src.outline_walk.OutlineHits` and the frame
        tuple of :func:`_outline_deltas` (with gradients).
    """
    sg = jax.lax.stop_gradient
    h, w = cam.height, cam.width
    p_cam = world_to_camera(cam, vertices)
    fx, fy = focal_lengths(cam)
    xs, ys = screen_to_camera(
        cam, jnp.arange(w, dtype=jnp.float32) + 0.5, jnp.arange(h, dtype=jnp.float32) + 0.5
    )
    zero = jnp.zeros((), xs.dtype)
    # From a pixel's ray (z = 1) to its right neighbour's: 1 / fx further along camera x; to the
    # one below: 1 / fy further down, i.e. along -y.
    steps = jnp.stack([jnp.stack([1.0 / fx, zero, zero]), jnp.stack([zero, -1.0 / fy, zero])])
    gx, gy = jnp.meshgrid(sg(xs), sg(ys))
    rays = jnp.stack([gx, gy, jnp.ones_like(gx)], axis=-1).reshape(h * w, 3)
    # Depth only orders the pair; the blend's gradient comes from the edge.
    depth = sg(depth)
    still = sg(p_cam)
    normals, onward = edge_planes(still, faces, across)
    near = (
        near_silhouettes(onward, faces, camera_to_screen(cam, still), still[:, 2], (h, w))
        if cull
        else jnp.ones((h, w), bool)
    )
    walks = _walks_kernel(background, max(_MIN_LANES, 2 * h * w // _LANE_SHARE))
    found = walks(normals, onward, near, tri, depth, rays, sg(steps))
    frame = (p_cam, faces, tri.reshape(-1), depth.reshape(-1), xs, ys, steps, (fx, fy))
    return found, frame


@jax.jit
def _compiled_antialias(cam, vertices, faces, across, tri, depth, color, bg):
    """:func:`analytic_antialias` of checked arrays, as one compiled program.

    An eager call runs it compiled once per shapes; op by op, its outline walks would
    compile again at every call (seconds each) and round apart from the jitted pass.
    Under the caller's ``jit`` (or ``vmap``, ``grad``) the call is inlined.
    """
    sg = jax.lax.stop_gradient
    h, w = cam.height, cam.width
    pixels, cols = h * w, color.shape[-1]
    found, frame = _walk_frame(cam, vertices, faces, across, tri, depth, background=bg is not None)
    flat = color.reshape(pixels, cols)
    slots = 2 * pixels
    block = min(slots, max(_MIN_LANES, slots // _LISTED_SHARE))
    at, deltas = _outline_deltas(found, found.hits[:block], frame, flat, bg)
    out = flat.at[at].add(deltas, mode="drop")
    # Listed pairs beyond the first block: the image only (the loop carries no gradient).
    still = jax.tree_util.tree_map(sg, (frame, flat, bg))
    hits = jnp.pad(found.hits, (0, block), constant_values=slots)

    def more(state):
        start, extra = state
        part = jax.lax.dynamic_slice(hits, (start,), (block,))
        at, deltas = _outline_deltas(found, part, *still)
        return start + block, extra.at[at].add(deltas, mode="drop")

    first = (jnp.asarray(block, jnp.int32), jnp.zeros_like(flat))
    _, extra = jax.lax.while_loop(lambda s: s[0] < found.hit_count, more, first)
    return (out + extra).reshape(h, w, cols)


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
