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
  the chunk size, not by the mesh, and no step touches the whole frame.
* Coverage uses edge functions evaluated in a canonical edge direction, so
  the two triangles sharing an edge compute the same two products, compared
  (not subtracted: no contraction rounds them apart) with opposite senses;
  the top-left fill rule breaks exact ties.  Shared edges are
  therefore drawn exactly once, with no holes and no double coverage.

Everything is written for one camera; batch cameras (or posed vertices) with
``jax.vmap``: the frame kernel's batching rule (:func:`jaxgfx._src.frames.per_frame`)
renders the frames one after the other on the CPU and as one vectorized program
elsewhere, on the devices the batch lives on.  An eager call runs the frame compiled.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec

from jaxgfx._src.camera import (
    Camera,
    as_float32,
    validate_camera,
    world_to_camera,
    world_to_camera_soa,
)
from jaxgfx._src.checks import check_int, require_finite, require_indices
from jaxgfx._src.eager import compiled_when_eager
from jaxgfx._src.frames import batch_mesh, check_batching, per_frame, shard
from jaxgfx._src.precision import in_32bit
from jaxgfx._src.raster_tangents import cross3, dot3, pixel_rays, shading_tangents
from jaxgfx._src.zbuffer import (
    CHUNK,
    NO_TRI,
    TRI_BATCH,
    ClippedTriangles,
    TriangleSetup,
    _chunk_fragments,
    _frame_visibility,
    _work_list,
    clip_near,
    corners_soa,
    triangle_setup,
    visibility,
)
from jaxgfx._src.zsplit import resolve_devices, split_visible_faces

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
    "vertex_normals",
]

_NO_TRI = NO_TRI


class RasterOutput(NamedTuple):
    """Result of :func:`rasterize` for one camera."""

    color: jax.Array  # (H, W, C) interpolated attributes, 0 where empty
    depth: jax.Array  # (H, W) camera-space z, +inf where empty
    tri_id: jax.Array  # (H, W) int32 index into faces, -1 where empty
    bary: jax.Array  # (H, W, 3) perspective-correct barycentrics, 0 where empty


def validate_mesh(vertices, faces, attributes=None, *, where: str | None = None) -> None:
    """Checks mesh arrays; raises ``ValueError``/``TypeError`` naming the problem.

    Shapes and dtypes are checked on abstract values too (the checks hold inside ``jit``);
    values (finite vertices, face indices in range) where they are concrete, and inside
    :func:`~jaxgfx.checks.checked` while the program runs.  Otherwise, under ``jit``,
    out-of-range face indices are clamped to ``[0, V)``, as JAX clamps gather indices.

    Args:
        vertices: (V, 3) floats, all finite.
        faces: (F, 3) integers in ``[0, V)``.
        attributes: optional (V, C) per-vertex attributes, all finite.
        where: the function that checks, named in the messages of :func:`~jaxgfx.checks.checked`.
    """
    v_shape, f_shape = np.shape(vertices), np.shape(faces)
    if len(v_shape) != 2 or v_shape[-1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {v_shape}")
    if not jnp.issubdtype(jnp.result_type(vertices), jnp.floating):
        raise TypeError(f"vertices must be floating point, got {jnp.result_type(vertices)}")
    if len(f_shape) != 2 or f_shape[-1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {f_shape}")
    if not jnp.issubdtype(jnp.result_type(faces), jnp.integer):
        raise TypeError(f"faces must be integer indices, got {jnp.result_type(faces)}")
    if attributes is not None:
        a_shape = np.shape(attributes)
        if len(a_shape) != 2 or a_shape[0] != v_shape[0]:
            raise ValueError(
                f"attributes must have shape (V, C) with V={v_shape[0]}, got {a_shape}"
            )
        if not jnp.issubdtype(jnp.result_type(attributes), jnp.number):
            raise TypeError(f"attributes must be numbers, got {jnp.result_type(attributes)}")
        if not isinstance(attributes, jax.core.Tracer) and not np.all(
            np.isfinite(np.asarray(attributes))
        ):
            raise ValueError("attributes must be finite")
    if not isinstance(vertices, jax.core.Tracer):
        v = np.asarray(vertices)
        if not np.all(np.isfinite(v)):
            bad = int(np.count_nonzero(~np.isfinite(v).all(axis=1)))
            raise ValueError(f"vertices must be finite: {bad} vertices contain NaN or inf")
    if not isinstance(faces, jax.core.Tracer):
        f = np.asarray(faces)
        if f.size and (f.min() < 0 or f.max() >= v_shape[0]):
            raise ValueError(
                f"faces index out of range: indices span [{f.min()}, {f.max()}] "
                f"but there are {v_shape[0]} vertices"
            )
    require_finite("vertices", vertices, where)
    require_indices("faces", faces, v_shape[0], "vertices", where)
    if attributes is not None:
        require_finite("attributes", attributes, where)


def coverage_count(
    cam: Camera, vertices: jax.Array, faces: jax.Array, *, block: int = 2, chunk: int = CHUNK
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
    starts, offsets, total = _work_list(setup.nblocks)
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
    hit = face_id != _NO_TRI
    g = jnp.take(p_cam.reshape(-1, 9), jnp.where(hit, face_id, 0), axis=0, mode="clip").T
    return _resolve_rows(cam, g, inv_depth, face_id)


def _resolve_rows(cam, g, inv_depth, face_id, row0=0, rows=None):
    """:func:`resolve` from the visible face's 9 camera-space corner values per pixel.

    ``g``: 9 arrays (H*W,) (or a (9, H*W) array): corner-major x, y, z.  With ``rows``
    (static) the pixels are image rows ``row0 .. row0 + rows`` only.
    """
    # Structure of arrays, pixels last: one row gather of the face's 9 corner values
    # per pixel, then (N,) vectors.  (An (N, 3) layout with jnp.cross is ~3x slower on
    # XLA:CPU.)
    ray = pixel_rays(cam, row0, rows)
    h = cam.height if rows is None else rows
    w = cam.width
    hit = face_id != _NO_TRI
    p0 = (g[0], g[1], g[2])
    e1 = (g[3] - g[0], g[4] - g[1], g[5] - g[2])
    e2 = (g[6] - g[0], g[7] - g[1], g[8] - g[2])
    hvec = cross3(ray, e2)
    det = dot3(e1, hvec)
    good = hit & (jnp.abs(det) > 1e-12 * (dot3(e1, e1) * dot3(e2, e2) + 1e-30))
    inv_det = 1.0 / jnp.where(good, det, 1.0)
    svec = (-p0[0], -p0[1], -p0[2])
    u = dot3(svec, hvec) * inv_det
    qvec = cross3(svec, e1)
    v = dot3(ray, qvec) * inv_det
    t = dot3(e2, qvec) * inv_det
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
    """Interpolates per-vertex attributes (V, C) at pixels -> (H, W, C); 0 where empty.

    Args:
        attributes: (V, C) per-vertex values.
        faces: (F, 3) vertex indices.
        tri_id: (...) face per pixel, -1 where empty.
        bary: (..., 3) barycentrics.

    Out-of-range ``faces`` or ``tri_id`` are clamped by the gathers, except inside
    :func:`~jaxgfx.checks.checked`, which raises ``ValueError`` naming them.
    """
    require_indices("faces", faces, np.shape(attributes)[0], "attribute rows", "interpolate")
    require_indices(
        "tri_id", tri_id, np.shape(faces)[0], "faces", "interpolate", allow_minus_one=True
    )
    fv = _face_corners(faces, jnp.maximum(tri_id, 0).reshape(-1))
    return _interpolate_corners(attributes, fv, tri_id, bary)


def _interpolate_corners(attributes, fv, tri_id, bary):
    """:func:`interpolate` from each pixel's 3 vertex indices ``fv`` (3 arrays (N,))."""
    c = attributes.shape[-1]
    # Per pixel: its face's 3 vertex indices, then 1-D gathers per corner and channel,
    # channels-first (an (..., 3, C) product summed over its corner axis costs ~50x
    # more on XLA:CPU).  No (F, 3C) table: for large meshes its fresh memory (page
    # faults) costs more than the gathers.
    a = attributes.T  # (C, V)
    b = bary.reshape(-1, 3).T
    out = jnp.stack(
        [
            b[0] * jnp.take(a[ch], fv[0], mode="clip")
            + b[1] * jnp.take(a[ch], fv[1], mode="clip")
            + b[2] * jnp.take(a[ch], fv[2], mode="clip")
            for ch in range(c)
        ]
    )
    out = jnp.where(tri_id.reshape(-1) >= 0, out, 0.0)
    return out.T.reshape(*tri_id.shape, c)


def _face_corners(faces, face_id):
    """The 3 vertex indices of face ``face_id`` (N,) as 3 arrays (N,).

    The callers then gather 1-D arrays (one per corner and coordinate), which fuse
    into their consumers on XLA:CPU; an (N, 9) row gather and its transpose are
    materialised (28 MB each for 1024x768 pixels, fresh memory every call).
    """
    fv = jnp.take(faces, face_id, axis=0, mode="clip")  # (N, 3): no (3, F) copy of faces
    return [fv[:, k] for k in range(3)]


@in_32bit
def rasterize(
    cam: Camera,
    vertices: jax.Array,
    faces: jax.Array,
    attributes: jax.Array | None = None,
    *,
    cull_backfaces: bool = False,
    block: int = 2,
    chunk: int = CHUNK,
    devices: int | Sequence[jax.Device] | None = None,
    batching: str = "auto",
) -> RasterOutput:
    """Renders a triangle mesh with a z-buffer.

    Front faces are those whose vertices run counter-clockwise seen from the
    camera (outward normals for trimesh meshes).  Everything is computed in float32
    (the z-buffer compares 1/z bit patterns), also under ``jax_enable_x64``.

    Batches: ``jax.vmap`` over cameras and/or posed vertices renders a batch in one
    program.  On a CPU the frames run one after the other (each with its own loop trip
    counts), elsewhere as one vectorized program (``batching``).  The work runs where the
    inputs are: a batch sharded over a mesh along its leading axis
    (``jax.device_put(cams, NamedSharding(mesh, P("batch")))``) is split over the mesh's
    devices, each rendering its own frames.

    Args:
        cam: the shared camera (resolution static).
        vertices: (V, 3) world positions.
        faces: (F, 3) int vertex indices; under ``jit`` out-of-range indices are
            clamped to ``[0, V)`` (eager calls and :func:`~jaxgfx.checks.checked` raise).
        attributes: (V, C) per-vertex attributes (colour, normal, ...);
            default: the world positions.
        cull_backfaces: drop faces that point away from the camera.
        block: tile edge in pixels for the work list (static).
        chunk: work items (tiles) per z-buffer pass (static); bounds memory at
            ``chunk * block**2`` fragments.
        devices: split this ONE frame's faces over several devices (static): an int D
            (the first D of ``jax.devices()``) or a sequence of devices; ``None`` or 1: one
            device.  On a CPU with one host device per core this draws a frame on every
            core; the result is bit-identical to one device (each device z-buffers every
            D-th face over the whole frame, and the buffers merge by the z-buffer's own
            rule: nearest depth, then lowest face index).  An explicit choice, because it
            makes the call an SPMD program over those devices.  Under ``jax.vmap`` the
            z-buffer split is dropped (a batch is split by its own sharding, never twice);
            the shading still gives each device its rows of every frame.
        batching: the ``vmap`` rule (static): ``"auto"`` (frame by frame on CPU,
            vectorized elsewhere), ``"frames"`` or ``"vectorized"``.

    Returns:
        :class:`RasterOutput` with colour (H, W, C), depth (H, W) (camera z,
        +inf where empty), triangle id (H, W) and barycentrics (H, W, 3).

    Gradients:
        ``depth``, ``bary`` and ``color`` are differentiable (forward and reverse mode)
        with respect to ``vertices``, ``attributes`` and the camera's float fields
        (position, rotation, focal lengths, principal point) wherever coverage does not
        change: the visible face of each pixel is found without gradients, then the
        pixel's ray is intersected with that face differentiably, its tangents in closed
        form (the intersection's 3x3 system), so a reverse pass is a few products and
        one scatter of corner cotangents per pixel beside the frame.  Coverage itself is
        piecewise constant, so moving an edge across a pixel has no derivative here; for
        images whose silhouettes have gradients with respect to vertices and camera,
        pass this output to
        :func:`jaxgfx.silhouette.analytic_antialias`.  ``near``/``far`` act only through
        coverage and get zero gradient; at grazing faces (ray almost in the face's plane)
        the depth falls back to the z-buffer's and its gradient is zero.

    Raises:
        ValueError: bad shapes or static arguments (also inside ``jit``), bad values of
            concrete inputs, and of traced ones inside :func:`~jaxgfx.checks.checked`:
            non-finite vertices, attributes or camera fields, face indices out of range,
            a focal length <= 0, a zero rotation, ``near <= 0`` or ``far <= near``.
        TypeError: bad dtypes or types of static arguments.
    """
    check_int("block", block, low=1)
    check_int("chunk", chunk, low=1)
    if not isinstance(cull_backfaces, (bool, np.bool_)):
        raise TypeError(f"cull_backfaces must be a bool, got {type(cull_backfaces).__name__}")
    check_batching(batching)
    split = None if devices is None else resolve_devices(devices)
    cam = as_float32(validate_camera(cam, where="rasterize"))
    validate_mesh(vertices, faces, attributes, where="rasterize")
    vertices = jnp.asarray(vertices, jnp.float32)
    faces = jnp.clip(jnp.asarray(faces, jnp.int32), 0, max(vertices.shape[0] - 1, 0))
    attributes = vertices if attributes is None else jnp.asarray(attributes, jnp.float32)
    if faces.shape[0] == 0 or vertices.shape[0] == 0:
        return RasterOutput(*_empty_frame(cam.height, cam.width, attributes.shape[-1]))
    static = (bool(cull_backfaces), int(block), int(chunk), batching)
    if split is not None and len(split) > 1:
        return _rasterize_split(static, split, cam, vertices, faces, attributes)
    return _compiled_rasterize(static, cam, vertices, faces, attributes)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _rasterize(static, cam, vertices, faces, attributes):
    """:func:`rasterize` of checked arrays: visibility and shading of one frame.

    ``jax.vmap`` follows :func:`_raster_kernel`'s batching rule; gradients come from
    :func:`_rasterize_jvp`.
    """
    return RasterOutput(*_raster_kernel(*static)(cam, vertices, faces, attributes))


@_rasterize.defjvp
def _rasterize_jvp(static, primals, tangents):
    # Which face a pixel sees is piecewise constant in the inputs: its derivative is zero
    # wherever it exists.  So the frame is rendered as without gradients, and the tangents
    # come from the differentiable part alone, each pixel's ray intersected with its (now
    # fixed) face, in closed form (raster_tangents).  The z-buffer's while_loop and
    # scatters stay out of JVPs/VJPs (reverse mode cannot go through a while_loop).
    cam, vertices, faces, attributes = primals
    t_cam, t_vertices, _, t_attributes = tangents
    out = _rasterize(static, *primals)
    t_out = shading_tangents(
        cam, vertices, faces, attributes, out.depth, out.tri_id, out.bary,
        t_cam, t_vertices, t_attributes,
    )  # fmt: skip
    return out, RasterOutput(*t_out)


# One jitted frame, eager calls and traced ones alike (under a caller's jit it is inlined).
_compiled_rasterize = jax.jit(_rasterize, static_argnums=0)


@functools.cache
def _raster_kernel(cull_backfaces: bool, block: int, chunk: int, batching: str):
    """Visibility and shading of one frame, with the ``batching`` rule under ``vmap``."""

    def frame(cam, vertices, faces, attributes):
        # One set of camera-space vertices for the z-buffer and the shading: its loops take
        # them as an operand, so they are written out once, and the shading's per-pixel
        # gather reads them (computed inside it, XLA recomputed the camera rotation for
        # every gathered value).
        p_cam = world_to_camera_soa(cam, vertices)
        inv_depth, face_id = _frame_visibility(
            cam, vertices, p_cam, faces, cull_backfaces, block, chunk, TRI_BATCH
        )

        def shade():
            return _shade(cam, p_cam.T, faces, attributes, inv_depth, face_id)

        def shade_unless_empty():
            # Besides skipping the shading of an empty frame, the branch makes the shading
            # write buffers of its own.  In a batch run frame by frame (lax.map), XLA:CPU
            # otherwise fuses the frame's last pass into the update of the stacked output,
            # an in-place loop it runs on one thread (0.96 against 0.52 ms a bunny frame at
            # 512x384); behind the branch that pass runs on every core and the batch copies
            # its result.  Off the CPU the batch is vectorized, and a branch would cost a
            # host sync per frame: none there.
            empty = functools.partial(_empty_frame, cam.height, cam.width, attributes.shape[-1])
            return jax.lax.cond(jnp.any(face_id != _NO_TRI), shade, empty)

        return jax.lax.platform_dependent(cpu=shade_unless_empty, default=shade)

    return per_frame(frame, batching)


def _empty_frame(h: int, w: int, c: int):
    """The outputs of a frame in which no face is visible: colour, depth, ids, barycentrics."""
    return (
        jnp.zeros((h, w, c), jnp.float32),
        jnp.full((h, w), jnp.inf, jnp.float32),
        jnp.full((h, w), -1, jnp.int32),
        jnp.zeros((h, w, 3), jnp.float32),
    )


def _shade(cam, pv, faces, attributes, inv_depth, face_id):
    """Colour, depth, ids and barycentrics of one frame from its visibility (flat H*W).

    ``pv``: (V, 3) camera-space vertices.
    """
    return _shade_rows(cam, pv, faces, attributes, inv_depth, face_id, 0, cam.height)


def _rasterize_split(static, split, cam, vertices, faces, attributes):
    """``rasterize(devices=D)``: one frame's faces z-buffered on D devices, rows shaded per device.

    The visible faces are found without gradients (``stop_gradient``: which face a pixel
    sees is piecewise constant); the rows' shading is differentiated by autodiff (one frame's
    rows per device), not by :func:`_rasterize`'s closed-form tangents.
    """
    cull_backfaces, block, chunk, batching = static
    cam_c, vertices_c = jax.lax.stop_gradient((cam, vertices))
    inv_depth, face_id = split_visible_faces(
        cam_c,
        vertices_c,
        faces,
        split,
        cull_backfaces=cull_backfaces,
        block=block,
        chunk=chunk,
        tri_batch=TRI_BATCH,
        batching=batching,
    )
    pv = world_to_camera(cam, vertices)  # (V, 3)
    args = (cam, pv, faces, attributes, inv_depth, face_id)
    if cam.height % len(split) == 0:
        return RasterOutput(*_split_shade_fn(split)(*args))
    return RasterOutput(*_shade_rows(*args, 0, cam.height))


def _shade_rows(cam, pv, faces, attributes, inv, fid, row0, h: int):
    """Colour, depth, face id and barycentrics of image rows ``row0 .. row0 + h`` (static h).

    ``pv``: (V, 3) camera-space vertices; ``inv``, ``fid``: the rows' (h * W,) 1/z and
    visible face from the z-buffer.
    """
    w = cam.width

    def shade(first, rows: int, inv, fid):
        # The visible face's camera-space corners, gathered per pixel (not an (F, 3, 3)
        # table: see interpolate).
        fv = jnp.take(faces, jnp.where(fid != _NO_TRI, fid, 0), axis=0, mode="clip")
        # One materialised (9, N) block (a stripe: at most 9 MB): the resolve's fusion
        # then reads the same inputs whatever the batch, so its rounding does not
        # depend on how a sweep splits frames over devices (1-D gathers fused into it
        # gave depths 1.5e-6 apart).
        g = jnp.take(pv, fv.reshape(-1), axis=0, mode="clip").reshape(-1, 9).T
        depth, tri_id, bary = _resolve_rows(cam, g, inv, fid, first, rows)
        # The same corner indices again (tri_id is fid or -1 -> face 0 as above): one
        # per-pixel gather of faces less (terrain 1024x768: frame -7 %, bunny -13 %).
        colour = _interpolate_corners(attributes, [fv[:, k] for k in range(3)], tri_id, bary)
        return colour, depth, tri_id, bary

    stripes = _stripes(h, w)
    if stripes == 1:
        return shade(row0, h, inv, fid)
    rows = h // stripes

    def in_stripes(inv, fid):
        # XLA:CPU: a large frame is shaded a stripe of rows at a time, because the
        # per-pixel temporaries of a whole 1024x768 frame (~40 MB) come fresh from the OS
        # every call (page faults).  An accelerator shades the frame in one wide pass: a
        # loop over stripes would only add dependent steps there.
        out = jax.lax.map(
            lambda a: shade(row0 + a[0] * rows, rows, a[1], a[2]),
            (
                jnp.arange(stripes, dtype=jnp.int32),
                inv.reshape(stripes, -1),
                fid.reshape(stripes, -1),
            ),
        )
        return tuple(x.reshape(h, w, *x.shape[3:]) for x in out)

    return jax.lax.platform_dependent(
        inv, fid, cpu=in_stripes, default=functools.partial(shade, row0, h)
    )


@functools.cache
def _split_shade_fn(devices: tuple):
    """Shading of a frame split by rows over ``devices`` (``rasterize(devices=)``).

    Each device shades its H/D rows (the z-buffer result is on every device after the
    merge); the result is sharded by rows.  Plain ``shard_map`` (differentiable); under
    ``jax.vmap`` each device shades its rows of every frame.
    """
    d = len(devices)
    axis = "rows"

    def local(cam, pv, faces, attributes, inv, fid):
        r = cam.height // d
        start = jax.lax.axis_index(axis) * r
        part = [
            jax.lax.dynamic_slice_in_dim(x, start * cam.width, r * cam.width) for x in (inv, fid)
        ]
        return _shade_rows(cam, pv, faces, attributes, *part, start, r)

    return shard(
        local, batch_mesh(devices, axis), (PartitionSpec(),) * 6, (PartitionSpec(axis),) * 4
    )


def _stripes(h: int, w: int, pixels: int = 1 << 18) -> int:
    """The fewest stripes of whole rows, dividing ``h``, with at most ``pixels`` each."""
    for n in range(1, h + 1):
        if h % n == 0 and (h // n) * w <= pixels:
            return n
    return h


@compiled_when_eager
def vertex_normals(vertices: jax.Array, faces: jax.Array) -> jax.Array:
    """Area-weighted unit vertex normals (V, 3)."""
    t = vertices[faces]
    n = jnp.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    acc = jnp.zeros_like(vertices).at[faces.reshape(-1)].add(jnp.repeat(n, 3, axis=0))
    nn = jnp.sum(acc * acc, -1, keepdims=True)
    ok = nn > 0
    return jnp.where(ok, acc / jnp.sqrt(jnp.where(ok, nn, 1.0)), jnp.array([0.0, 1.0, 0.0]))
