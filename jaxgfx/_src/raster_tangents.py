"""The rasterizer's derivative: tangents of a frame's shading, in closed form.

Which face a pixel sees is piecewise constant in the vertices and the camera, so a frame's
derivative is that of its shading: each pixel's ray ``r`` (camera space, ``z = 1``) meets
its face's plane at ``X = t r = p0 + u e1 + v e2`` (``e1 = p1 - p0``, ``e2 = p2 - p0``).
Differentiating, with barycentrics ``b = (1 - u - v, u, v)``::

    dt r - du e1 - dv e2 = b0 dp0 + b1 dp1 + b2 dp2 - t dr

a 3x3 system ``M (dt, du, dv) = dX`` with ``M = [r, -e1, -e2]``, whose inverse has the rows
``(e1 x e2, r x e2, e1 x r) / (r . (e1 x e2))``.  So the tangents are three dot products per
pixel with vectors of the primal frame, applied to the bary-weighted motion of the face's
corners.

Written so, the linear part is a gather of the corners' tangents, products with per-pixel
primal values and sums; its transpose (reverse mode) is those products and one scatter-add
of each pixel's three corner cotangents.  Autodiff's linearization of the intersection as
the shading computes it kept the intersection's chain of operations per pixel in its
transpose, fused by XLA:CPU into the loop writing the nine corner cotangents, and the
reverse cost up to twice as much (the engine's design notes have the measurements).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, screen_to_camera, world_to_camera

__all__ = ["cross3", "dot3", "pixel_rays", "shading_tangents"]


def cross3(a, b):
    """Cross product of two 3-tuples of (N,) arrays (structure of arrays)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def dot3(a, b):
    """Dot product of two 3-tuples of (N,) arrays (structure of arrays)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def pixel_rays(cam: Camera, row0=0, rows: int | None = None):
    """Camera-space rays (``z = 1``) through the pixel centres of image rows ``row0 ..
    row0 + rows`` (static ``rows``; default every row), as a structure of arrays.

    Returns:
        ``(x, y, z)``, each (rows * W,), row-major.
    """
    w = cam.width
    h = cam.height if rows is None else rows
    rows_y = row0 + jnp.arange(h, dtype=jnp.int32)
    xs, ys = screen_to_camera(
        cam, jnp.arange(w, dtype=jnp.float32) + 0.5, rows_y.astype(jnp.float32) + 0.5
    )
    return (
        jnp.broadcast_to(xs[None, :], (h, w)).reshape(-1),
        jnp.broadcast_to(ys[:, None], (h, w)).reshape(-1),
        jnp.ones((h * w,), jnp.float32),
    )


def shading_tangents(
    cam: Camera,
    vertices: jax.Array,
    faces: jax.Array,
    attributes: jax.Array,
    depth: jax.Array,
    tri_id: jax.Array,
    bary: jax.Array,
    t_cam: Camera,
    t_vertices: jax.Array,
    t_attributes: jax.Array,
) -> tuple[jax.Array, jax.Array, np.ndarray, jax.Array]:
    """Tangents of one frame's colour, depth, ids and barycentrics (module docstring).

    Args:
        cam, vertices (V, 3), faces (F, 3), attributes (V, C): the frame's inputs.
        depth (H, W), tri_id (H, W), bary (H, W, 3): its rasterized output.
        t_cam, t_vertices, t_attributes: the inputs' tangents.

    Returns:
        ``(t_color (H, W, C), t_depth (H, W), t_tri_id (H, W) float0, t_bary (H, W, 3))``;
        zero where no face is seen and, for depth and barycentrics, at grazing faces (ray
        almost in the face's plane), whose depth and barycentrics fall back to constants.
    """
    h, w = cam.height, cam.width
    tri = tri_id.reshape(-1)
    hit = tri >= 0
    fv = jnp.take(faces, jnp.maximum(tri, 0), axis=0, mode="clip")  # (N, 3)
    corner = [fv[:, k] for k in range(3)]
    pv, t_pv = jax.jvp(world_to_camera, (cam, vertices), (t_cam, t_vertices))
    ray, t_ray = jax.jvp(pixel_rays, (cam,), (t_cam,))  # t_ray[2] is 0: z stays 1
    # Primal: the face's corners (1-D gathers: no (N, 3) cross products, slow on XLA:CPU).
    p = [tuple(jnp.take(pv[:, a], c, mode="clip") for a in range(3)) for c in corner]
    e1 = tuple(p[1][a] - p[0][a] for a in range(3))
    e2 = tuple(p[2][a] - p[0][a] for a in range(3))
    normal = cross3(e1, e2)
    det = dot3(ray, normal)
    # The rasterizer's own test for a grazing face (|e1 . (r x e2)| is |det|).
    good = hit & (jnp.abs(det) > 1e-12 * (dot3(e1, e1) * dot3(e2, e2) + 1e-30))
    inv = jnp.where(good, 1.0 / jnp.where(good, det, 1.0), 0.0)
    # The rows of M^-1, each scaled once here: the linear part (and its transpose) then
    # reads three vectors a pixel.
    m_t, m_u, m_v = (
        tuple(x * inv for x in row) for row in (normal, cross3(ray, e2), cross3(e1, ray))
    )
    b = bary.reshape(-1, 3)
    t = jnp.where(good, depth.reshape(-1), 0.0)
    # Linear: the bary-weighted motion of the corners, less the ray's, then M^-1.
    t_p = [jnp.take(t_pv, c, axis=0, mode="clip") for c in corner]  # (N, 3) each
    moved = b[:, 0:1] * t_p[0] + b[:, 1:2] * t_p[1] + b[:, 2:3] * t_p[2]
    d_x = (moved[:, 0] - t * t_ray[0], moved[:, 1] - t * t_ray[1], moved[:, 2])
    dt, du, dv = dot3(m_t, d_x), dot3(m_u, d_x), dot3(m_v, d_x)
    t_bary = jnp.stack([-du - dv, du, dv], axis=-1)
    # Colour: sum_k b_k a_k moves with u and v along the attributes' edges, and with the
    # attributes' own tangents.
    a = [jnp.take(attributes, c, axis=0, mode="clip") for c in corner]  # (N, C) each
    t_a = [jnp.take(t_attributes, c, axis=0, mode="clip") for c in corner]
    t_color = (
        du[:, None] * (a[1] - a[0])
        + dv[:, None] * (a[2] - a[0])
        + b[:, 0:1] * t_a[0]
        + b[:, 1:2] * t_a[1]
        + b[:, 2:3] * t_a[2]
    )
    t_color = jnp.where(hit[:, None], t_color, 0.0)
    return (
        t_color.reshape(h, w, -1),
        dt.reshape(h, w),
        np.zeros((h, w), jax.dtypes.float0),
        t_bary.reshape(h, w, 3),
    )
