"""Depth-buffer compositing of render passes, background and simple shading.

Every pass renders with the same camera into a (colour, depth) frame; the
frames are merged by keeping the nearest sample per pixel (thesis 2.4.2,
Fig. 2.3).  The background pass initialises the colour buffer with a sky and
the depth buffer with +inf (thesis 2.3.1).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxgfx._src.camera import Camera, pixel_rays, validate_camera
from jaxgfx._src.checks import checking, require_values
from jaxgfx._src.eager import compiled_when_eager

__all__ = [
    "Frame",
    "composite",
    "composite_pair",
    "coverage",
    "background",
    "lambert",
    "fog",
    "depth_image",
    "to_uint8",
]


class Frame(NamedTuple):
    """One pass's output for one camera."""

    color: jax.Array  # (H, W, 3) float in [0, 1]
    depth: jax.Array  # (H, W) camera-space z, +inf where the pass drew nothing


def composite_pair(base: Frame, top: Frame) -> Frame:
    """Merges two frames per pixel by depth; on an exact tie ``base`` wins."""
    nearer = top.depth < base.depth
    return Frame(
        jnp.where(nearer[..., None], top.color, base.color),
        jnp.where(nearer, top.depth, base.depth),
    )


def composite(frames) -> Frame:
    """Depth-composites a sequence of frames (thesis 2.4.2).

    Args:
        frames: non-empty sequence of :class:`Frame` with equal shapes; the
            first is usually the background pass.

    Returns:
        The merged :class:`Frame`.
    """
    frames = list(frames)
    if not frames:
        raise ValueError("composite: frames must be a non-empty sequence")
    shapes = {tuple(f.depth.shape) for f in frames}
    if len(shapes) != 1:
        raise ValueError(f"composite: frames have different shapes {sorted(shapes)}")
    out = frames[0]
    for f in frames[1:]:
        out = composite_pair(out, f)
    return out


def coverage(frames) -> jax.Array:
    """Share of the frame each pass shows after :func:`composite` (ties go to the earlier pass).

    Where no pass drew (every depth +inf) the composite keeps the first frame, usually
    the background pass, so that frame is counted there and the shares sum to one.

    Args:
        frames: non-empty sequence of :class:`Frame` with equal shapes, in compositing order.

    Returns:
        (P,) float32: for each pass, the fraction of pixels it shows.
    """
    frames = list(frames)
    if not frames:
        raise ValueError("coverage: frames must be a non-empty sequence")
    # argmin takes the first minimum, as composite_pair keeps its base on a tie.
    nearest = jnp.argmin(jnp.stack([f.depth for f in frames]), axis=0)
    onehot = nearest[None] == jnp.arange(len(frames))[:, None, None]
    return jnp.mean(onehot.astype(jnp.float32), axis=(1, 2))


def _sqrt_up(x):
    """``sqrt(clip(x, 0, 1))`` with finite derivatives: 0 where ``x <= 0`` (double where: the
    untaken branch never sees sqrt's infinite slope at 0, which times 0 is NaN)."""
    above = x > 0
    return jnp.where(above, jnp.sqrt(jnp.where(above, jnp.minimum(x, 1.0), 1.0)), 0.0)


def background(
    cam: Camera,
    horizon=(0.78, 0.86, 0.95),
    zenith=(0.30, 0.50, 0.85),
    ground=(0.42, 0.40, 0.37),
) -> Frame:
    """Background pass: a sky gradient by view elevation, depth +inf (thesis 2.3.1).

    Pass the same colour three times for a flat background.
    """
    validate_camera(cam, where="background")  # a NaN view direction would be a NaN sky
    return _background(cam, horizon, zenith, ground)


def _background_of(cam: Camera, horizon, zenith, ground) -> Frame:
    """:func:`background` of a checked camera."""
    _, d = pixel_rays(cam, normalize=True)
    up = d[..., 1:2]
    hz = jnp.asarray(horizon, jnp.float32)
    sky = hz + (jnp.asarray(zenith, jnp.float32) - hz) * _sqrt_up(up)
    gnd = hz + (jnp.asarray(ground, jnp.float32) - hz) * _sqrt_up(-up)
    color = jnp.where(up >= 0, sky, gnd)
    return Frame(color, jnp.full(color.shape[:2], jnp.inf, jnp.float32))


_background = compiled_when_eager(_background_of)


def lambert(
    normals: jax.Array,
    albedo: jax.Array,
    light_dir=(0.4, 0.8, 0.3),
    ambient: float = 0.3,
    two_sided: bool = True,
) -> jax.Array:
    """Lambert shading ``albedo * (ambient + (1 - ambient) * max(n.l, 0))``.

    Args:
        normals: (..., 3) surface normals (need not be unit; zeros are safe).
        albedo: (..., 3) base colour.
        light_dir: direction *towards* the light.
        ambient: ambient fraction in [0, 1].
        two_sided: use ``|n.l|`` so faces seen from behind are lit too.
    """
    light = jnp.asarray(light_dir, jnp.float32)
    light = light / jnp.linalg.norm(light)
    nn = jnp.sum(normals * normals, -1, keepdims=True)
    n = normals / jnp.sqrt(jnp.where(nn > 0, nn, 1.0))
    ndl = jnp.sum(n * light, -1, keepdims=True)
    ndl = jnp.abs(ndl) if two_sided else jnp.maximum(ndl, 0.0)
    return albedo * (ambient + (1.0 - ambient) * ndl)


def fog(frame: Frame, fog_color=(0.78, 0.86, 0.95), density: float = 0.0) -> Frame:
    """Exponential distance fog ``mix(color, fog, 1 - exp(-density * depth))``.

    Far geometry fades into what lies behind it: pass the background pass's colour
    (``background(cam).color``, an (H, W, 3) image) as ``fog_color`` and every pixel fades
    into the sky seen through it, so a distant object melts into the sky's gradient
    instead of standing out as a flat cut-out of one fog colour.

    Args:
        frame: the composited frame.
        fog_color: (3,) one colour, or (H, W, 3) a colour per pixel (the sky behind).
        density: fog per unit of depth, >= 0.

    Returns:
        The fogged :class:`Frame`; pixels with infinite depth (background) are left as
        they are.
    """
    fc = jnp.asarray(fog_color, jnp.float32)
    if fc.shape not in ((3,), tuple(frame.color.shape)):
        raise ValueError(
            f"fog_color must be (3,) or the frame's shape {tuple(frame.color.shape)}, "
            f"got {fc.shape}"
        )
    if isinstance(density, (int, float)) and not density >= 0:  # traced values pass
        raise ValueError(f"density must be >= 0, got {density}")
    if checking():  # and inside jaxgfx.checked, traced ones too: NaN fogs every pixel
        d = jnp.asarray(density)
        require_values("density", (d >= 0) & jnp.isfinite(d), d, "{} must be >= 0", "fog")
    finite = jnp.isfinite(frame.depth)
    z = jnp.where(finite, frame.depth, 0.0)
    k = (1.0 - jnp.exp(-density * z))[..., None]
    c = frame.color * (1.0 - k) + fc * k
    return Frame(jnp.where(finite[..., None], c, frame.color), frame.depth)


@compiled_when_eager
def depth_image(depth: jax.Array, near=None, far=None) -> jax.Array:
    """Depth as a grey image: bright near, dark far, black where empty (Fig. 2.3).

    Uses inverse depth, normalised between ``near`` and ``far`` (default: the
    finite range of ``depth``), which spreads the grey levels the way a
    hardware depth buffer does.

    Returns:
        (H, W) float in [0, 1].
    """
    finite = jnp.isfinite(depth) & (depth > 0)
    zmin = jnp.min(jnp.where(finite, depth, jnp.inf)) if near is None else jnp.asarray(near)
    zmax = jnp.max(jnp.where(finite, depth, -jnp.inf)) if far is None else jnp.asarray(far)
    zmin = jnp.where(jnp.isfinite(zmin), zmin, 1.0)
    zmax = jnp.where(jnp.isfinite(zmax), zmax, 1.0)
    inv = 1.0 / jnp.where(finite, depth, 1.0)
    lo, hi = 1.0 / zmax, 1.0 / zmin
    span = jnp.where(hi > lo, hi - lo, 1.0)
    g = 0.1 + 0.9 * jnp.clip((inv - lo) / span, 0.0, 1.0)
    return jnp.where(finite, g, 0.0)


def to_uint8(img) -> jax.Array:
    """[0, 1] floats -> uint8 (values outside are clipped, NaN becomes 0)."""
    img = jnp.nan_to_num(jnp.asarray(img, jnp.float32), nan=0.0)
    return (jnp.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(jnp.uint8)
