"""Screen-space post-processing for voxel frames (thesis 4.5.6).

* :func:`smooth` — the depth-aware smoothing filter of Fig. 4.17: find the
  minimum depth on a circle of 8 samples, then average a 5 x 5 box whose
  footprint scales with that depth, using only samples close to it.
* :func:`antialias` — 2x1 / 2x2 full-screen anti-aliasing by down-sampling
  a frame rendered at 2W x H or 2W x 2H (4.5.6.2).
* :func:`screen_space_normals` — normals recovered from the depth buffer
  (Eq. 4.7) with random sample offsets reciprocal to the depth.
* :func:`ambient_occlusion` and :func:`shade` — SSAO from the same kind of
  samples, and Lambert shading from the recovered normals.
* :func:`shade_voxels` — the three together for a ray-cast voxel frame, with
  sample radii measured in voxels (what ``jaxgfx render-voxels`` and the
  demo's voxel pass draw).

Images are (H, W, C) float32, depths (H, W) camera-space z with +inf where
empty; every function works on one frame and is vmap-able.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from jaxgfx._src.camera import Camera, focal_length, screen_to_camera
from jaxgfx._src.eager import compiled_when_eager

__all__ = [
    "antialias",
    "smooth",
    "screen_space_normals",
    "ambient_occlusion",
    "shade",
    "shade_voxels",
]


def _sample(img, ys, xs):
    """Nearest sample with clamped coordinates; img (H, W, ...)."""
    H, W = img.shape[:2]
    yi = jnp.clip(jnp.round(ys).astype(jnp.int32), 0, H - 1)
    xi = jnp.clip(jnp.round(xs).astype(jnp.int32), 0, W - 1)
    return img[yi, xi]


def antialias(color, depth, factor: tuple[int, int] = (2, 1)):
    """Down-samples a super-sampled frame (4.5.6.2).

    The thesis's 2x1 AA renders the *same view* with twice the horizontal
    samples (pixels half as wide as tall) and averages horizontal pairs.
    Render the frame with ``jaxgfx.camera.supersampled(cam, factor)`` (same
    view, focal lengths and principal point scaled) and pass it here with the same factor.

    Args:
        color: (H * fy, W * fx, C).
        depth: (H * fy, W * fx).
        factor: static ``(fx, fy)``: (2, 1) for 2x1 AA, (2, 2) for 2x2 AA.

    Returns:
        ``(color (H, W, C), depth (H, W))``: the colour mean and the nearest depth.
    """
    fx, fy = factor
    if fx < 1 or fy < 1:
        raise ValueError(f"factor must be positive, got {factor}")
    Hs, Ws = depth.shape
    if Hs % fy or Ws % fx:
        raise ValueError(f"frame {Ws}x{Hs} is not divisible by the AA factor {factor}")
    H, W = Hs // fy, Ws // fx
    c = color.reshape(H, fy, W, fx, -1).mean(axis=(1, 3))
    d = depth.reshape(H, fy, W, fx).min(axis=(1, 3))
    return c, d


@compiled_when_eager
def smooth(
    color,
    depth,
    *,
    radius: float = 2.0,
    scale: float = 30.0,
    max_step: float = 1.5,
    threshold: float = 0.05,
):
    """Depth-aware smoothing of voxel silhouettes and near voxels (Fig. 4.17).

    Args:
        color: (H, W, C).
        depth: (H, W), +inf where empty.
        radius: radius in pixels of the 8-sample circle for the minimum depth.
        scale: box-filter step in pixels is ``min(scale / z_min, max_step)``, so
            near voxels (large on screen) are smoothed over a larger area.
        max_step: largest box-filter step in pixels.
        threshold: relative depth band around ``z_min`` that is averaged.

    Returns:
        ``(color, depth)``; pixels with nothing near them are returned unchanged.
    """
    H, W = depth.shape
    ys, xs = jnp.meshgrid(jnp.arange(H, dtype=jnp.float32), jnp.arange(W, dtype=jnp.float32),
                          indexing="ij")  # fmt: skip
    ang = jnp.arange(8) * (jnp.pi / 4)
    zmin = depth
    for a in ang:
        zmin = jnp.minimum(zmin, _sample(depth, ys + radius * jnp.sin(a), xs + radius * jnp.cos(a)))
    finite = jnp.isfinite(zmin)
    safe = jnp.where(finite, zmin, 1.0)
    step = jnp.minimum(scale / jnp.maximum(safe, 1e-6), max_step)
    acc = jnp.zeros_like(color)
    wsum = jnp.zeros_like(depth)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            sy, sx = ys + dy * step, xs + dx * step
            d = _sample(depth, sy, sx)
            ok = jnp.isfinite(d) & (
                jnp.abs(jnp.where(jnp.isfinite(d), d, 0.0) - safe) <= threshold * safe
            )
            w = jnp.where(ok & finite, 1.0, 0.0)
            acc = acc + w[..., None] * _sample(color, sy, sx)
            wsum = wsum + w
    out = jnp.where((wsum > 0)[..., None], acc / jnp.maximum(wsum, 1.0)[..., None], color)
    return out, jnp.where(wsum > 0, jnp.minimum(depth, zmin), depth)


def _screen_samples(depth: jax.Array, scale, max_radius: float):
    """Pixel grid, hit mask, safe depth and a sample radius in pixels shrinking with depth."""
    H, W = depth.shape
    ys, xs = jnp.meshgrid(jnp.arange(H, dtype=jnp.float32), jnp.arange(W, dtype=jnp.float32),
                          indexing="ij")  # fmt: skip
    finite = jnp.isfinite(depth)
    z = jnp.where(finite, depth, 1.0)
    return H, W, ys, xs, finite, z, jnp.clip(scale / z, 1.0, max_radius)


def _offsets(key, n, H, W):
    k1, k2 = jax.random.split(key)
    r = jax.random.uniform(k1, (n,), minval=0.3, maxval=1.0)
    a = jax.random.uniform(k2, (n,), maxval=2 * jnp.pi)
    return r * jnp.cos(a), r * jnp.sin(a)


@functools.partial(compiled_when_eager, static_argnames=("samples",))
def screen_space_normals(
    cam: Camera, depth, *, key, samples: int = 16, scale: float | jax.Array = 40.0
):
    """Normals from the depth buffer (Eq. 4.7), in camera space (x right, y up, z forward).

    For each of ``samples`` random offsets, whose size in pixels is reciprocal
    to the pixel's depth (``scale / z``), the depth differences along x and y
    (``dz_x``, ``dz_y``) give two tangents of the surface, here taken between the
    camera-space points of the pixels so that the perspective is exact; their
    cross product, turned towards the camera, is the normal.

    Args:
        cam: the camera the depth was rendered with.
        depth: (H, W), +inf where empty.
        key: ``jax.random`` key for the sample offsets (same key, same result).
        samples: number of random samples (the thesis uses at least 16).
        scale: sample radius in pixels times depth.

    Returns:
        (H, W, 3) unit normals; (0, 0, -1) where the depth is empty.
    """
    H, W, ys, xs, finite, z, rad = _screen_samples(depth, scale, 8.0)
    ox, oy = _offsets(key, samples, H, W)

    def point(zz, x, y):
        # Camera-space point of pixel centre (x, y) at depth zz.
        rx, ry = screen_to_camera(cam, x + 0.5, y + 0.5)
        return jnp.stack([zz * rx, zz * ry, zz], axis=-1)

    p0 = point(z, xs, ys)

    def one_sample(k, tangents):
        tx, ty = tangents
        dx = jnp.round(jnp.where(ox[k] >= 0, 1.0, -1.0) * jnp.maximum(jnp.abs(ox[k]) * rad, 1.0))
        dy = jnp.round(jnp.where(oy[k] >= 0, 1.0, -1.0) * jnp.maximum(jnp.abs(oy[k]) * rad, 1.0))
        zx = _sample(depth, ys, xs + dx)
        zy = _sample(depth, ys + dy, xs)
        # Only neighbours on the same surface (Eq. 4.7's dz_x, dz_y).
        okx = jnp.isfinite(zx) & (jnp.abs(jnp.where(jnp.isfinite(zx), zx, z) - z) < 0.2 * z)
        oky = jnp.isfinite(zy) & (jnp.abs(jnp.where(jnp.isfinite(zy), zy, z) - z) < 0.2 * z)
        px = point(jnp.where(okx, zx, z), xs + dx, ys)
        py = point(jnp.where(oky, zy, z), xs, ys + dy)
        tx = tx + jnp.where(okx[..., None], (px - p0) / dx[..., None], 0.0)
        ty = ty + jnp.where(oky[..., None], (py - p0) / dy[..., None], 0.0)
        return tx, ty

    # A loop, not an unrolled Python for: one compiled body whatever ``samples`` is.
    zero = jnp.zeros_like(p0)
    tx, ty = jax.lax.fori_loop(0, samples, one_sample, (zero, zero))
    n = jnp.cross(tx, ty)
    n = jnp.where((n[..., 2:3] > 0), -n, n)  # face the camera
    norm = jnp.linalg.norm(n, axis=-1, keepdims=True)
    n = jnp.where(norm > 1e-12, n / jnp.where(norm > 1e-12, norm, 1.0), jnp.array([0.0, 0.0, -1.0]))
    return jnp.where(finite[..., None], n, jnp.array([0.0, 0.0, -1.0]))


def ambient_occlusion(
    depth,
    *,
    key,
    samples: int = 16,
    scale: float | jax.Array = 60.0,
    bias: float = 0.5,
    max_gap: float | jax.Array | None = None,
):
    """Screen-space ambient occlusion from random depth samples (Fig. 4.19).

    A sample occludes the pixel when it is nearer by more than ``bias`` and by
    less than ``max_gap`` (farther in front it is another object, not a crease).

    Args:
        depth: (H, W), +inf where empty.
        key: ``jax.random`` key for the sample offsets.
        samples: number of random samples.
        scale: sample radius in pixels times depth.
        bias: smallest depth difference that occludes.
        max_gap: largest depth difference that occludes, in depth units; None:
            ``4 * radius * z / 60 + 4`` (grows with the sample radius).

    Returns:
        (H, W) ambient factor in [0, 1] (1 = unoccluded; 1 where empty).
    """
    H, W, ys, xs, finite, z, rad = _screen_samples(depth, scale, 16.0)
    ox, oy = _offsets(key, samples, H, W)

    def one_sample(k, occ):
        d = _sample(depth, ys + oy[k] * rad, xs + ox[k] * rad)
        d = jnp.where(jnp.isfinite(d), d, jnp.inf)
        gap = 4.0 * rad * z / 60.0 + 4.0 if max_gap is None else max_gap
        closer = (d < z - bias) & (z - d < gap)
        return occ + closer

    occ = jax.lax.fori_loop(0, samples, one_sample, jnp.zeros_like(z))
    ao = 1.0 - occ / samples
    return jnp.where(finite, ao, 1.0)


def shade(color, normals, ao=None, *, light=(0.4, 0.6, -0.7), ambient: float = 0.35):
    """Lambert shading from camera-space normals, times ambient occlusion.

    Args:
        color: (H, W, 3) albedo.
        normals: (H, W, 3) camera-space unit normals.
        ao: optional (H, W) ambient factor.
        light: direction towards the light, camera space.
        ambient: ambient term.
    """
    ldir = jnp.asarray(light, jnp.float32)
    ldir = ldir / jnp.linalg.norm(ldir)
    lam = jnp.clip(jnp.sum(normals * ldir, axis=-1), 0.0, 1.0)
    a = 1.0 if ao is None else ao
    return jnp.clip(color * (ambient * a + (1.0 - ambient) * lam)[..., None], 0.0, 1.0)


def shade_voxels(
    cam: Camera,
    color,
    depth,
    *,
    key,
    samples: int = 16,
    normal_radius: float | jax.Array = 3.0,
    ao_radius: float | jax.Array = 3.0,
    background=(0.0, 0.0, 0.0),
):
    """Lights a ray-cast voxel frame: screen-space normals, SSAO and Lambert (4.5.6).

    The depth buffer is all the ray caster gives about the surface's shape, so
    the normals come from it (:func:`screen_space_normals`, Eq. 4.7) and the
    ambient term is darkened where nearer samples surround a pixel
    (:func:`ambient_occlusion`).  Both sample radii are given in scene units
    (voxels for a voxel-space camera) and turned into pixels with the camera's
    focal length, so the look does not change with the frame size or the
    distance: a normal radius of a few voxels (3 by default) smooths the stair steps
    of the voxel faces into the surface's shape (1.5 leaves them as contour lines on a
    256-voxel bunny; larger radii smooth more at the cost of small detail).
    ``samples`` is static (jit with it fixed); the radii may be traced.

    Args:
        cam: the camera the frame was rendered with (the supersampled one when
            anti-aliasing; shade before :func:`antialias`).
        color: (H, W, 3) albedo in [0, 1].
        depth: (H, W) camera-space z, +inf where empty.
        key: ``jax.random`` key for the sample offsets.
        samples: random samples for the normals and for the occlusion each.
        normal_radius: normal sample radius in scene units.
        ao_radius: occlusion sample radius in scene units.
        background: (3,) colour of empty pixels.

    Returns:
        (H, W, 3) shaded colour in [0, 1].
    """
    for name, value in (("normal_radius", normal_radius), ("ao_radius", ao_radius)):
        if isinstance(value, (int, float)) and not value > 0:  # traced values pass unchecked
            raise ValueError(f"{name} must be > 0, got {value}")
    f = focal_length(cam)  # pixels per scene unit at depth 1
    kn, ka = jax.random.split(key)
    normals = screen_space_normals(cam, depth, key=kn, samples=samples, scale=normal_radius * f)
    # Occluders up to twice the sample radius in front: creases and contacts darken,
    # a distant object in front of another casts no halo.
    ao = ambient_occlusion(
        depth, key=ka, samples=samples, scale=ao_radius * f, max_gap=2.0 * ao_radius
    )
    lit = shade(color, normals, ao)
    bg = jnp.asarray(background, jnp.float32)
    return jnp.where(jnp.isfinite(depth)[..., None], lit, bg)
