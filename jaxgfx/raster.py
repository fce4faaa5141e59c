"""Z-buffer triangle rasterizer in pure JAX (no graphics context).

The rasterizer is *deferred* (a visibility buffer): it first finds, for every
pixel, the nearest triangle, and then shades each pixel once by intersecting
its view ray with that triangle, which gives exact perspective-correct
barycentric coordinates and depth.

Design for large meshes (the thesis's terrain has ~700 k triangles at
1024x768, Table 3.1):

* Triangles are clipped against the near plane in camera space (a crossing
  triangle becomes one or two triangles, never dropped or smeared).
* Each clipped triangle's screen bounding box is cut into ``block x block``
  pixel tiles; the (triangle, tile) pairs form a flat work list enumerated
  through a prefix sum, so tiny triangles cost one tile and huge ones many,
  with no per-triangle padding to the largest size.
* The work list is processed in fixed-size chunks by a ``lax.while_loop``;
  each chunk scatters inverse depth into the z-buffer (max of 1/z) and then
  the winning triangle id (min id among exact ties), so memory is bounded by
  the chunk size, not by the mesh.
* Coverage uses edge functions evaluated in a canonical edge direction, so
  the two triangles sharing an edge compute bit-identical values with
  opposite signs; the top-left fill rule breaks exact ties.  Shared edges are
  therefore drawn exactly once, with no holes and no double coverage.

Everything is written for one camera; batch cameras with ``jax.vmap``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx.camera import (
    Camera,
    focal_lengths,
    screen_to_camera,
    validate_camera,
    world_to_camera,
)

__all__ = [
    "RasterOutput",
    "ClippedTriangles",
    "TriangleSetup",
    "validate_mesh",
    "corners_soa",
    "clip_near",
    "triangle_setup",
    "visibility",
    "coverage_count",
    "resolve",
    "interpolate",
    "rasterize",
    "face_normals",
    "vertex_normals",
]

_NO_TRI = np.int32(np.iinfo(np.int32).max)


class RasterOutput(NamedTuple):
    """Result of :func:`rasterize` for one camera."""

    color: jax.Array  # (H, W, C) interpolated attributes, 0 where empty
    depth: jax.Array  # (H, W) camera-space z, +inf where empty
    tri_id: jax.Array  # (H, W) int32 index into faces, -1 where empty
    bary: jax.Array  # (H, W, 3) perspective-correct barycentrics, 0 where empty


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

    Kept SoA on purpose: a (T, 20) layout would need a transpose of the whole
    array, which costs more on XLA:CPU than gathering 20 rows per work item.
    """

    packed: jax.Array  # (20, T) float32, rows as in the _AX.._S0Y constants
    ints: jax.Array  # (6, T) int32 rows: lo_x, lo_y, hi_x, hi_y, nblocks_x, source face
    nblocks: jax.Array  # (T,) int32 tiles in the bbox, 0 for culled triangles


# Column layout of TriangleSetup.packed: canonical edge start (ax, ay), edge
# direction (dx, dy) and inside sign for the 3 edges, then the 1/z plane.
_AX, _AY, _DX, _DY, _SG = 0, 3, 6, 9, 12
_W0, _GX, _GY, _S0X, _S0Y = 15, 16, 17, 18, 19


def validate_mesh(vertices, faces, attributes=None) -> None:
    """Checks concrete mesh arrays; raises ``ValueError``/``TypeError`` naming the problem.

    Args:
        vertices: (V, 3) floats, all finite.
        faces: (F, 3) integers in ``[0, V)``.
        attributes: optional (V, C) per-vertex attributes, all finite.
    """
    if isinstance(vertices, jax.core.Tracer) or isinstance(faces, jax.core.Tracer):
        return
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[-1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {v.shape}")
    if not np.issubdtype(v.dtype, np.floating):
        raise TypeError(f"vertices must be floating point, got {v.dtype}")
    if not np.all(np.isfinite(v)):
        bad = int(np.count_nonzero(~np.isfinite(v).all(axis=1)))
        raise ValueError(f"vertices must be finite: {bad} vertices contain NaN or inf")
    if f.ndim != 2 or f.shape[-1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise TypeError(f"faces must be integer indices, got {f.dtype}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(
            f"faces index out of range: indices span [{f.min()}, {f.max()}] "
            f"but there are {len(v)} vertices"
        )
    if attributes is not None and not isinstance(attributes, jax.core.Tracer):
        a = np.asarray(attributes)
        if a.ndim != 2 or a.shape[0] != len(v):
            raise ValueError(f"attributes must have shape (V, C) with V={len(v)}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("attributes must be finite")


def corners_soa(cam: Camera, vertices: jax.Array, faces: jax.Array) -> jax.Array:
    """Camera-space triangle corners as (3 coords, 3 corners, F)."""
    pc = world_to_camera(cam, vertices).T  # (3, V)
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
    verts = jnp.concatenate([first, two_b], axis=-1)
    valid = jnp.concatenate([n_in > 0, n_in == 2])
    source = jnp.concatenate([jnp.arange(f, dtype=jnp.int32)] * 2)
    return ClippedTriangles(verts, valid, source)


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
    sx = jnp.where(tris.valid, 0.5 * cam.width + flx * x / z, 0.0)
    sy = jnp.where(tris.valid, 0.5 * cam.height - fly * y / z, 0.0)
    qx, qy = jnp.roll(sx, -1, axis=0), jnp.roll(sy, -1, axis=0)  # edge i: p_i -> p_{i+1}
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
    lo_x = jnp.clip(jnp.ceil(jnp.min(sx, 0) - 0.5), 0.0, cam.width).astype(jnp.int32)
    lo_y = jnp.clip(jnp.ceil(jnp.min(sy, 0) - 0.5), 0.0, cam.height).astype(jnp.int32)
    hi_x = jnp.clip(jnp.floor(jnp.max(sx, 0) - 0.5), -1.0, cam.width - 1.0).astype(jnp.int32)
    hi_y = jnp.clip(jnp.floor(jnp.max(sy, 0) - 0.5), -1.0, cam.height - 1.0).astype(jnp.int32)
    ext_x = jnp.maximum(hi_x - lo_x + 1, 0)
    ext_y = jnp.maximum(hi_y - lo_y + 1, 0)
    nbx = (ext_x + block - 1) // block
    nby = (ext_y + block - 1) // block
    alive = tris.valid & keep & (area2 != 0) & (ext_x > 0) & (ext_y > 0)
    nblocks = jnp.where(alive, nbx * nby, 0).astype(jnp.int32)
    packed = jnp.concatenate(
        [ax, ay, dx, dy, sign, jnp.stack([w[0], gx, gy, sx[0], sy[0]])], axis=0
    )
    ints = jnp.stack([lo_x, lo_y, hi_x, hi_y, jnp.maximum(nbx, 1), tris.source], axis=0)
    return TriangleSetup(packed, ints.astype(jnp.int32), nblocks)


def _chunk_fragments(cam, setup, starts, offsets, total, chunk0, chunk, block):
    """Fragments of work items ``chunk0 .. chunk0+chunk``: (pixel index, 1/z, face id, ok)."""
    item = chunk0 + jnp.arange(chunk, dtype=jnp.int32)
    live = item < total
    t = jnp.searchsorted(offsets, item, side="right").astype(jnp.int32)
    t = jnp.minimum(t, offsets.shape[0] - 1)
    row = jnp.take(setup.packed, t, axis=1)  # (20, K)
    irow = jnp.take(setup.ints, t, axis=1)  # (6, K)
    local = item - starts[t]
    nbx = irow[4]
    x0 = irow[0] + (local % nbx) * block
    y0 = irow[1] + (local // nbx) * block
    off = jnp.arange(block, dtype=jnp.int32)
    px = x0[:, None, None] + off[None, None, :]  # (K, 1, B)
    py = y0[:, None, None] + off[None, :, None]  # (K, B, 1)
    px, py = jnp.broadcast_arrays(px, py)  # (K, B, B)
    cx = px.astype(jnp.float32) + 0.5
    cy = py.astype(jnp.float32) + 0.5

    def col(i):
        return row[i][:, None, None]

    inside = live[:, None, None]
    for e in range(3):
        v = col(_SG + e) * (col(_DX + e) * (cy - col(_AY + e)) - col(_DY + e) * (cx - col(_AX + e)))
        # Top-left rule: a centre exactly on an edge belongs to the triangle
        # on the edge's canonical "+" side only.
        inside = inside & ((v > 0) | ((v == 0) & (col(_SG + e) > 0)))
    w = col(_W0) + col(_GX) * (cx - col(_S0X)) + col(_GY) * (cy - col(_S0Y))
    ok = (
        inside
        & (px <= irow[2][:, None, None])
        & (py <= irow[3][:, None, None])
        & (w <= 1.0 / cam.near)
        & (w >= 1.0 / cam.far)
    )
    npix = cam.width * cam.height
    pix = jnp.where(ok, py * cam.width + px, npix)
    fid = jnp.broadcast_to(irow[5][:, None, None], pix.shape)
    return pix.reshape(-1), w.reshape(-1), fid.reshape(-1), ok.reshape(-1)


def visibility(
    cam: Camera, setup: TriangleSetup, block: int, chunk: int
) -> tuple[jax.Array, jax.Array]:
    """Nearest face per pixel by a chunked z-buffer over (triangle, tile) work items.

    Returns:
        ``(inv_depth, face_id)`` flat (H*W,): the largest 1/z (0 where empty)
        and the face index (``_NO_TRI`` where empty).
    """
    npix = cam.width * cam.height
    offsets = jnp.cumsum(setup.nblocks)
    starts = offsets - setup.nblocks
    total = offsets[-1] if offsets.shape[0] else jnp.int32(0)

    def fragments(c0):
        pix, w, fid, ok = _chunk_fragments(cam, setup, starts, offsets, total, c0, chunk, block)
        # The z-buffer holds the bit patterns of 1/z as int32: for positive
        # floats they order like the values and an integer max is exact.
        wb = jax.lax.bitcast_convert_type(jnp.where(ok, w, 0.0), jnp.int32)
        return jnp.where(ok, pix, npix), wb, fid

    # Software-pipelined loop: iteration k computes the fragments of chunk k
    # into the loop carry and z-tests those of chunk k-1 from the carry.  The
    # scatter and the winner test below must see bit-identical depths; a loop
    # carry is a materialised buffer, whereas values inside one iteration may
    # be recomputed by two XLA fusions with different FMA contraction (and
    # XLA:CPU drops optimization barriers).
    def cond(state):
        return state[0] < total + chunk

    def body(state):
        c0, zbuf, ibuf, pix, wb, fid = state
        new_z = zbuf.at[pix].max(wb, mode="drop")
        best = new_z.at[pix].get(mode="fill", fill_value=-1)
        win = wb == best
        cand = (
            jnp.full((npix,), _NO_TRI, jnp.int32)
            .at[jnp.where(win, pix, npix)]
            .min(fid, mode="drop")
        )
        # A pixel takes this chunk's face only if the chunk brought it nearer;
        # on an exact tie the earlier chunk (lower face index) keeps it.
        ibuf = jnp.where((cand != _NO_TRI) & (new_z > zbuf), cand, ibuf)
        return (c0 + chunk, new_z, ibuf, *fragments(c0))

    zbuf = jnp.zeros((npix,), jnp.int32)
    ibuf = jnp.full((npix,), _NO_TRI, jnp.int32)
    n_frag = chunk * block * block
    empty = (
        jnp.full((n_frag,), npix, jnp.int32),
        jnp.zeros((n_frag,), jnp.int32),
        jnp.zeros((n_frag,), jnp.int32),
    )
    _, zbuf, ibuf, *_ = jax.lax.while_loop(cond, body, (jnp.int32(0), zbuf, ibuf, *empty))
    return jax.lax.bitcast_convert_type(zbuf, jnp.float32), ibuf


def coverage_count(
    cam: Camera, vertices: jax.Array, faces: jax.Array, *, block: int = 2, chunk: int = 32768
) -> jax.Array:
    """How many faces cover each pixel centre, ignoring depth (overdraw).

    With the top-left rule a closed, non-overlapping tessellation of the screen
    covers every pixel exactly once; this is what the fill-rule tests check and
    what overdraw statistics report.

    Returns:
        (H, W) int32 counts.
    """
    validate_mesh(vertices, faces)
    vertices = jnp.asarray(vertices, jnp.float32)
    faces = jnp.asarray(faces, jnp.int32)
    tris = clip_near(corners_soa(cam, vertices, faces), cam.near)
    setup = triangle_setup(cam, tris, jnp.ones(tris.valid.shape, bool), block)
    offsets = jnp.cumsum(setup.nblocks)
    starts = offsets - setup.nblocks
    total = offsets[-1]
    npix = cam.width * cam.height

    def body(state):
        c0, acc = state
        pix, _, _, ok = _chunk_fragments(cam, setup, starts, offsets, total, c0, chunk, block)
        return c0 + chunk, acc.at[pix].add(ok.astype(jnp.int32), mode="drop")

    _, acc = jax.lax.while_loop(
        lambda st: st[0] < total, body, (jnp.int32(0), jnp.zeros((npix,), jnp.int32))
    )
    return acc.reshape(cam.height, cam.width)


def resolve(
    cam: Camera, p_cam: jax.Array, inv_depth: jax.Array, face_id: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per-pixel depth and perspective-correct barycentrics of the visible face.

    Intersects each pixel's view ray with the plane of its face (Moeller-Trumbore
    without the inside test), which is exact for any perspective.

    Returns:
        ``(depth (H,W), tri_id (H,W), bary (H,W,3))``.
    """
    h, w = cam.height, cam.width
    xs, ys = screen_to_camera(
        cam, jnp.arange(w, dtype=jnp.float32) + 0.5, jnp.arange(h, dtype=jnp.float32) + 0.5
    )
    gx, gy = jnp.meshgrid(xs, ys)
    ray = jnp.stack([gx, gy, jnp.ones_like(gx)], axis=-1).reshape(-1, 3)
    hit = face_id != _NO_TRI
    fid = jnp.where(hit, face_id, 0)
    tri = p_cam[fid]  # (N, 3, 3)
    p0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    hvec = jnp.cross(ray, e2)
    det = jnp.sum(e1 * hvec, -1)
    good = hit & (jnp.abs(det) > 1e-12 * (jnp.sum(e1 * e1, -1) * jnp.sum(e2 * e2, -1) + 1e-30))
    inv_det = 1.0 / jnp.where(good, det, 1.0)
    svec = -p0
    u = jnp.sum(svec * hvec, -1) * inv_det
    qvec = jnp.cross(svec, e1)
    v = jnp.sum(ray * qvec, -1) * inv_det
    t = jnp.sum(e2 * qvec, -1) * inv_det
    z_vis = 1.0 / jnp.where(inv_depth > 0, inv_depth, 1.0)
    # Grazing faces (det ~ 0): fall back to the z-buffer's depth and the
    # face centroid, which keeps everything finite.
    depth = jnp.where(good, t, z_vis)
    bary = jnp.stack([1.0 - u - v, u, v], axis=-1)
    bary = jnp.where(good[:, None], bary, 1.0 / 3.0)
    depth = jnp.where(hit, depth, jnp.inf)
    bary = jnp.where(hit[:, None], bary, 0.0)
    tri_id = jnp.where(hit, face_id, -1)
    return depth.reshape(h, w), tri_id.reshape(h, w), bary.reshape(h, w, 3)


def interpolate(attributes: jax.Array, faces: jax.Array, tri_id: jax.Array, bary: jax.Array):
    """Interpolates per-vertex attributes (V, C) at pixels -> (H, W, C); 0 where empty."""
    fid = jnp.maximum(tri_id, 0)
    corner = attributes[faces[fid]]  # (H, W, 3, C)
    out = jnp.sum(bary[..., None] * corner, axis=-2)
    return jnp.where((tri_id >= 0)[..., None], out, 0.0)


def rasterize(
    cam: Camera,
    vertices: jax.Array,
    faces: jax.Array,
    attributes: jax.Array | None = None,
    *,
    cull_backfaces: bool = False,
    block: int = 2,
    chunk: int = 32768,
) -> RasterOutput:
    """Renders a triangle mesh with a z-buffer.

    Front faces are those whose vertices run counter-clockwise seen from the
    camera (outward normals for trimesh meshes).

    Args:
        cam: the shared camera (resolution static).
        vertices: (V, 3) world positions.
        faces: (F, 3) int vertex indices.
        attributes: (V, C) per-vertex attributes (colour, normal, ...);
            default: the world positions.
        cull_backfaces: drop faces that point away from the camera.
        block: tile edge in pixels for the work list (static).
        chunk: work items (tiles) per z-buffer pass (static); bounds memory at
            ``chunk * block**2`` fragments.

    Returns:
        :class:`RasterOutput` with colour (H, W, C), depth (H, W) (camera z,
        +inf where empty), triangle id (H, W) and barycentrics (H, W, 3).

    Gradients:
        ``depth``, ``bary`` and ``color`` are differentiable (forward and reverse mode)
        with respect to ``vertices``, ``attributes`` and the camera's float fields
        (position, angles, fov) wherever coverage does not change: the visible face of
        each pixel is found without gradients, then the pixel's ray is intersected with
        that face differentiably.  Silhouette (coverage) gradients are therefore ZERO
        here: moving an edge across a pixel changes the image, but no derivative says so
        (use a soft rasterizer or edge sampling for those).  ``near``/``far`` act only
        through coverage and get zero gradient; at grazing faces (ray almost in the
        face's plane) the depth falls back to the z-buffer's and its gradient is zero.

    Raises:
        ValueError / TypeError: for bad concrete inputs (checked before tracing).
    """
    if not isinstance(block, int) or block <= 0:
        raise ValueError(f"block must be a positive int, got {block!r}")
    if not isinstance(chunk, int) or chunk <= 0:
        raise ValueError(f"chunk must be a positive int, got {chunk!r}")
    validate_camera(cam)
    validate_mesh(vertices, faces, attributes)
    vertices = jnp.asarray(vertices, jnp.float32)
    faces = jnp.asarray(faces, jnp.int32)
    attributes = vertices if attributes is None else jnp.asarray(attributes, jnp.float32)
    if faces.shape[0] == 0:
        h, w = cam.height, cam.width
        return RasterOutput(
            jnp.zeros((h, w, attributes.shape[-1]), jnp.float32),
            jnp.full((h, w), jnp.inf, jnp.float32),
            jnp.full((h, w), -1, jnp.int32),
            jnp.zeros((h, w, 3), jnp.float32),
        )
    p_cam = world_to_camera(cam, vertices)[faces]  # (F, 3, 3) for the per-pixel resolve
    # Which face a pixel sees is piecewise constant in the inputs: its derivative is zero
    # wherever it exists.  Cutting the gradient here says so, and keeps the z-buffer's
    # while_loop and scatters out of JVPs/VJPs (reverse mode cannot go through a while_loop).
    cam_c, vertices_c = jax.lax.stop_gradient((cam, vertices))
    tris = clip_near(corners_soa(cam_c, vertices_c, faces), cam_c.near)
    if cull_backfaces:
        tri_w = vertices_c[faces]
        n = jnp.cross(tri_w[:, 1] - tri_w[:, 0], tri_w[:, 2] - tri_w[:, 0])
        front = jnp.sum(n * (tri_w[:, 0] - cam_c.position), -1) < 0
        keep = jnp.concatenate([front, front])
    else:
        keep = jnp.ones(tris.valid.shape, bool)
    setup = triangle_setup(cam_c, tris, keep, block)
    inv_depth, face_id = visibility(cam_c, setup, block, chunk)
    depth, tri_id, bary = resolve(cam, p_cam, inv_depth, face_id)
    color = interpolate(attributes, faces, tri_id, bary)
    return RasterOutput(color, depth, tri_id, bary)


def face_normals(vertices: jax.Array, faces: jax.Array) -> jax.Array:
    """Unit face normals (F, 3) (zero-area faces give a finite unit fallback)."""
    t = vertices[faces]
    n = jnp.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    nn = jnp.sum(n * n, -1, keepdims=True)
    ok = nn > 0
    return jnp.where(ok, n / jnp.sqrt(jnp.where(ok, nn, 1.0)), jnp.array([0.0, 1.0, 0.0]))


def vertex_normals(vertices: jax.Array, faces: jax.Array) -> jax.Array:
    """Area-weighted unit vertex normals (V, 3)."""
    t = vertices[faces]
    n = jnp.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    acc = jnp.zeros_like(vertices).at[faces.reshape(-1)].add(jnp.repeat(n, 3, axis=0))
    nn = jnp.sum(acc * acc, -1, keepdims=True)
    ok = nn > 0
    return jnp.where(ok, acc / jnp.sqrt(jnp.where(ok, nn, 1.0)), jnp.array([0.0, 1.0, 0.0]))
