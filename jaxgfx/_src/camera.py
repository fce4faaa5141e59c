"""One pinhole camera shared by every render pass (thesis 2.3).

All passes (background, terrain, static objects, characters) use identical
view-point, orientation, field of view and resolution so their depth buffers
can be merged per pixel (thesis 2.4.2, Fig. 2.3).

Conventions (used by every module of jaxgfx):

* World: right-handed, **y up**, x-z is the ground plane.
* ``yaw`` rotates about +y; ``yaw = 0`` looks along +z, positive yaw turns
  the view towards +x.  ``pitch`` is positive looking up.  ``roll`` turns the
  image clockwise about the view axis.  All angles are radians inside the
  pytree; :func:`camera_from_degrees` takes degrees.
* Camera space: ``x`` right, ``y`` up, ``z`` forward (distance along the view
  axis).  *Depth* everywhere in jaxgfx means camera-space ``z``.
* Screen: pixel ``(i, j)`` = (column, row), row 0 at the top, pixel centres
  at ``(i + 0.5, j + 0.5)``.  Pixels are square unless ``pixel_aspect``
  (pixel width / height) says otherwise: :func:`supersampled` renders the
  same view on a finer grid for anti-aliasing (the thesis's 2x1 AA uses
  pixels half as wide, 4.5.6.2).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import (
    MAX_PIXELS,
    check_float,
    check_int,
    check_pixels,
    checking,
    require_finite,
    require_values,
    static_field,
)

__all__ = [
    "Camera",
    "camera_from_degrees",
    "look_at",
    "orbit_cameras",
    "camera_basis",
    "focal_length",
    "focal_lengths",
    "supersampled",
    "world_to_camera",
    "camera_to_screen",
    "screen_to_camera",
    "project",
    "pixel_rays",
    "camera_matrix",
    "view_matrix",
    "projection_matrix",
    "stack_cameras",
    "validate_camera",
    "as_float32",
    "frame_points",
    "MAX_PIXELS",
]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Camera:
    """Pinhole camera.  Array fields are pytree leaves; the resolution is static.

    Attributes:
        position: (3,) float32 world position of the eye.
        yaw: () radians about +y; 0 looks along +z.
        pitch: () radians, positive looks up.
        roll: () radians about the view axis.
        fov_y: () vertical field of view in radians, in (0, pi).
        near: () near clipping distance along the view axis, > 0.
        far: () far clipping distance, > near.
        width: static int, image width in pixels.
        height: static int, image height in pixels.
        pixel_aspect: static float, pixel width / pixel height (1 = square;
            0.5 for the thesis's 2x1 AA frame, see :func:`supersampled`).
    """

    position: jax.Array
    yaw: jax.Array
    pitch: jax.Array
    roll: jax.Array
    fov_y: jax.Array
    near: jax.Array
    far: jax.Array
    width: int = static_field(640)
    height: int = static_field(480)
    pixel_aspect: float = static_field(1.0)

    def __post_init__(self):
        # Lists and tuples become float32 arrays, so a camera written by hand
        # (``position=[0, 0, -5]``) is one leaf per field, as every kernel expects.
        for name in _FLOAT_FIELDS:
            value = getattr(self, name)
            if isinstance(value, (list, tuple)):
                object.__setattr__(self, name, np.asarray(value, np.float32))

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)``."""
        return (self.height, self.width)


_FLOAT_FIELDS = ("position", "yaw", "pitch", "roll", "fov_y", "near", "far")


def as_float32(cam: Camera) -> Camera:
    """``cam`` with every float field as float32 (the kernels' precision, also under x64)."""
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), cam)


def validate_camera(cam: Camera, *, where: str | None = None) -> Camera:
    """Checks a camera; raises ``TypeError``/``ValueError`` naming the field.

    Types, shapes and the resolution are checked on abstract values too, so the checks
    hold inside ``jit``; values (finite, ``fov_y`` in (0, pi), ``0 < near < far``) where
    they are concrete, and for traced cameras inside :func:`~jaxgfx.checks.checked` while the
    program runs.  A batched camera (leading axes, :func:`stack_cameras`) is accepted.

    Args:
        cam: the camera.
        where: the function that checks, named in the messages of value checks under
            :func:`~jaxgfx.checks.checked`.

    Raises:
        TypeError: ``cam`` is no :class:`Camera`, or a field has the wrong type.
        ValueError: a bad shape or value, or ``width * height`` over :data:`MAX_PIXELS`.
    """
    if not isinstance(cam, Camera):
        raise TypeError(f"cam must be a jaxgfx Camera, got {type(cam).__name__}")
    check_pixels(cam.width, cam.height)
    pa = cam.pixel_aspect
    if isinstance(pa, bool) or not isinstance(pa, (int, float, np.integer, np.floating)):
        raise TypeError(f"camera pixel_aspect must be a float, got {type(pa).__name__}")
    if not (math.isfinite(pa) and pa > 0):
        raise ValueError(f"camera pixel_aspect must be finite and > 0, got {pa}")
    for name in _FLOAT_FIELDS:
        value = getattr(cam, name)
        try:
            dtype = jnp.result_type(value)
        except TypeError:
            raise TypeError(
                f"camera {name} must be a number or array, got {type(value).__name__}"
            ) from None
        if not jnp.issubdtype(dtype, jnp.number) or jnp.issubdtype(dtype, jnp.complexfloating):
            raise TypeError(f"camera {name} must be real numbers, got {dtype}")
        shape = np.shape(value)
        if name == "position" and (len(shape) < 1 or shape[-1] != 3):
            raise ValueError(f"camera position must have shape (3,), got {shape}")
        if isinstance(value, jax.core.Tracer):
            continue
        arr = np.asarray(value)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"camera {name} must be finite, got {arr}")
    if not isinstance(cam.fov_y, jax.core.Tracer):
        fov = np.asarray(cam.fov_y)
        if np.any(fov <= 0) or np.any(fov >= math.pi):
            raise ValueError(
                f"camera fov_y must be in (0, pi) radians, got {fov} ({np.degrees(fov)} degrees)"
            )
    if not isinstance(cam.near, jax.core.Tracer) and not isinstance(cam.far, jax.core.Tracer):
        near, far = np.asarray(cam.near), np.asarray(cam.far)
        if np.any(near <= 0):
            raise ValueError(f"camera near must be > 0, got {near}")
        if np.any(far <= near):
            raise ValueError(f"camera far must be > near, got near={near}, far={far}")
    _require_camera_values(cam, where)
    return cam


def _require_camera_values(cam: Camera, where: str | None) -> None:
    """Under :func:`~jaxgfx.checks.checked`, the values :func:`validate_camera` checks.

    A NaN anywhere in the camera, or a field of no meaning, gives an empty or garbled frame.
    """
    if not checking():
        return
    for name in _FLOAT_FIELDS:
        require_finite(f"cam.{name}", getattr(cam, name), where)
    fov = jnp.asarray(cam.fov_y)
    require_values("cam.fov_y", (fov > 0) & (fov < math.pi), fov, "{} is outside (0, pi)", where)
    near, far = jnp.asarray(cam.near), jnp.asarray(cam.far)
    require_values("cam.near", near > 0, near, "{} must be > 0", where)
    require_values("cam.far", far > near, far, "{} must be > near", where)


def camera_from_degrees(
    position,
    yaw: float = 0.0,
    pitch: float = 0.0,
    roll: float = 0.0,
    fov: float = 60.0,
    width: int = 640,
    height: int = 480,
    near: float = 0.05,
    far: float = 1e4,
) -> Camera:
    """Builds a validated :class:`Camera` from angles in degrees.

    Args:
        position: (3,) eye position, y up.
        yaw: degrees about +y, 0 looks along +z.
        pitch: degrees, positive looks up.
        roll: degrees about the view axis.
        fov: vertical field of view in degrees.
        width: image width in pixels.
        height: image height in pixels.
        near: near plane distance.
        far: far plane distance.
    """
    width, height = check_pixels(width, height)
    fov = check_float("fov", fov)
    if not 0.0 < fov < 180.0:
        raise ValueError(f"fov must be in (0, 180) degrees, got {fov}")
    pos = np.asarray(position, dtype=np.float32)
    if pos.shape != (3,):
        raise ValueError(f"position must have shape (3,), got {pos.shape}")
    f32 = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    cam = Camera(
        position=jnp.asarray(pos),
        yaw=f32(math.radians(yaw)),
        pitch=f32(math.radians(pitch)),
        roll=f32(math.radians(roll)),
        fov_y=f32(math.radians(fov)),
        near=f32(near),
        far=f32(far),
        width=width,
        height=height,
    )
    return validate_camera(cam)


def camera_basis(cam: Camera) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Right, up and forward unit vectors of the camera in world space.

    The basis stays finite and smooth for a camera looking straight up or
    down: it is built from yaw/pitch/roll rotations, not from a cross product
    with the world up vector.

    Returns:
        ``(right, up, forward)``, each (3,).
    """
    cy, sy = jnp.cos(cam.yaw), jnp.sin(cam.yaw)
    cp, sp = jnp.cos(cam.pitch), jnp.sin(cam.pitch)
    cr, sr = jnp.cos(cam.roll), jnp.sin(cam.roll)
    forward = jnp.stack([sy * cp, sp, cy * cp])
    # Level right/up for this yaw; x-right on screen maps to -x world at yaw 0
    # because the world is right-handed with y up and the view looks along +z.
    right0 = jnp.stack([-cy, jnp.zeros_like(cy), sy])
    up0 = jnp.stack([-sy * sp, cp, -cy * sp])
    right = cr * right0 - sr * up0
    up = sr * right0 + cr * up0
    return right, up, forward


def focal_length(cam: Camera) -> jax.Array:
    """Vertical focal length in pixels: ``(height / 2) / tan(fov_y / 2)``."""
    return 0.5 * cam.height / jnp.tan(0.5 * cam.fov_y)


def focal_lengths(cam: Camera) -> tuple[jax.Array, jax.Array]:
    """Horizontal and vertical focal lengths in pixels, ``(f / pixel_aspect, f)``."""
    f = focal_length(cam)
    return f / cam.pixel_aspect, f


def supersampled(cam: Camera, factor: tuple[int, int]) -> Camera:
    """The same view on a grid ``factor = (fx, fy)`` times finer (anti-aliasing).

    The frame is ``fx W x fy H`` pixels of ``1 / fx`` by ``1 / fy`` of the
    original pixel, so :func:`jaxgfx.post.antialias` with the same factor
    gives back a ``W x H`` image of the original view.  ``(2, 1)`` is the
    thesis's 2x1 AA (pixels half as wide, 4.5.6.2), ``(2, 2)`` 2x2 AA.
    """
    try:
        fx, fy = (int(v) for v in factor)
    except (TypeError, ValueError):
        raise TypeError(f"factor must be a pair of ints, got {factor!r}") from None
    if fx < 1 or fy < 1:
        raise ValueError(f"factor must be positive, got {factor}")
    return validate_camera(
        dataclasses.replace(
            cam,
            width=cam.width * fx,
            height=cam.height * fy,
            pixel_aspect=cam.pixel_aspect * fy / fx,
        )
    )


def view_matrix(cam: Camera) -> jax.Array:
    """4x4 world -> camera matrix (rows: right, up, forward)."""
    right, up, forward = camera_basis(cam)
    rot = jnp.stack([right, up, forward])
    t = -rot @ cam.position
    top = jnp.concatenate([rot, t[:, None]], axis=1)
    return jnp.concatenate([top, jnp.array([[0.0, 0.0, 0.0, 1.0]], top.dtype)], axis=0)


def world_to_camera(cam: Camera, points: jax.Array) -> jax.Array:
    """World points (..., 3) -> camera space (..., 3); z is depth."""
    return jnp.stack(_camera_coords(cam, points), axis=-1)


def world_to_camera_soa(cam: Camera, points: jax.Array) -> jax.Array:
    """:func:`world_to_camera` of points (V, 3), laid out as (3, V) (x, y, z rows)."""
    return jnp.stack(_camera_coords(cam, points), axis=0)


def _camera_coords(cam: Camera, points: jax.Array) -> list[jax.Array]:
    """Camera-space x, y, z of world points (..., 3), each (...).

    Multiply-adds, not ``(points - position) @ rot.T``: XLA:CPU hands a (V, 3) x (3, 3)
    dot to its matrix library, many times slower than these fused multiply-adds.
    """
    d = [points[..., k] - cam.position[k] for k in range(3)]
    return [r[0] * d[0] + r[1] * d[1] + r[2] * d[2] for r in camera_basis(cam)]


def camera_to_screen(cam: Camera, p_cam: jax.Array) -> jax.Array:
    """Camera-space points (..., 3) -> pixel coordinates (..., 2).

    Points with ``z <= 0`` have no image; their coordinates are non-finite-safe
    garbage (the division is guarded) and must be masked by the caller using
    the depth.
    """
    fx, fy = focal_lengths(cam)
    z = p_cam[..., 2]
    safe_z = jnp.where(jnp.abs(z) > 1e-12, z, 1e-12)
    sx = 0.5 * cam.width + fx * p_cam[..., 0] / safe_z
    sy = 0.5 * cam.height - fy * p_cam[..., 1] / safe_z
    return jnp.stack([sx, sy], axis=-1)


def screen_to_camera(cam: Camera, sx, sy) -> tuple[jax.Array, jax.Array]:
    """Inverse of :func:`camera_to_screen` at depth 1.

    Screen x coordinates ``sx`` and y coordinates ``sy`` (any shapes, not
    broadcast against each other) map to the camera-space ``x / z`` and
    ``y / z`` of their rays.  Every pixel-ray construction uses this, so
    ``pixel_aspect`` is honoured in one place.
    """
    fx, fy = focal_lengths(cam)
    # One reciprocal, multiplied: XLA rewrites a division by a broadcast value so in
    # some programs (a vmapped batch of cameras) and not in others, and the rays'
    # last bits would then depend on the program.
    return (sx - 0.5 * cam.width) * (1.0 / fx), (0.5 * cam.height - sy) * (1.0 / fy)


def project(cam: Camera, points: jax.Array) -> tuple[jax.Array, jax.Array]:
    """World points (..., 3) -> (pixel xy (..., 2), depth (...)).

    Depth is the camera-space z (distance along the view axis); points behind
    the eye have depth <= 0.
    """
    p = world_to_camera(cam, points)
    return camera_to_screen(cam, p), p[..., 2]


def pixel_rays(cam: Camera, normalize: bool = True) -> tuple[jax.Array, jax.Array]:
    """One ray per pixel centre.

    Args:
        cam: the camera.
        normalize: if True, directions are unit vectors; if False they are
            scaled so that their camera-space z is 1 (ray parameter = depth).

    Returns:
        ``(origins, directions)``, each (H, W, 3) in world space.
    """
    xs, ys = screen_to_camera(
        cam,
        jnp.arange(cam.width, dtype=jnp.float32) + 0.5,
        jnp.arange(cam.height, dtype=jnp.float32) + 0.5,
    )
    gx, gy = jnp.meshgrid(xs, ys)
    right, up, forward = camera_basis(cam)
    d = gx[..., None] * right + gy[..., None] * up + forward
    if normalize:
        d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    o = jnp.broadcast_to(cam.position, d.shape)
    return o, d


def projection_matrix(cam: Camera) -> jax.Array:
    """4x4 camera -> clip matrix (OpenGL-style NDC in [-1, 1], z forward).

    ``clip = P @ [x, y, z, 1]``; ``ndc = clip[:3] / clip[3]`` with ``clip[3] = z``.
    """
    aspect = cam.width * cam.pixel_aspect / cam.height
    t = 1.0 / jnp.tan(0.5 * cam.fov_y)
    n, fa = cam.near, cam.far
    zero = jnp.zeros_like(t)
    one = jnp.ones_like(t)
    return jnp.stack(
        [
            jnp.stack([t / aspect, zero, zero, zero]),
            jnp.stack([zero, t, zero, zero]),
            jnp.stack([zero, zero, (fa + n) / (fa - n), -2 * fa * n / (fa - n)]),
            jnp.stack([zero, zero, one, zero]),
        ]
    )


def camera_matrix(cam: Camera) -> jax.Array:
    """4x4 world -> clip matrix: ``projection_matrix @ view_matrix``."""
    return projection_matrix(cam) @ view_matrix(cam)


def look_at(
    eye,
    target,
    fov: float = 60.0,
    width: int = 640,
    height: int = 480,
    near: float = 0.05,
    far: float = 1e4,
) -> Camera:
    """Camera at ``eye`` looking at ``target`` (degrees fov, no roll).

    Works for a view straight up or down (yaw is then taken as 0).
    """
    eye = np.asarray(eye, np.float64)
    d = np.asarray(target, np.float64) - eye
    n = np.linalg.norm(d)
    if not np.isfinite(n) or n == 0:
        raise ValueError("look_at: eye and target must be distinct finite points")
    d = d / n
    yaw = math.degrees(math.atan2(d[0], d[2])) if np.hypot(d[0], d[2]) > 1e-12 else 0.0
    pitch = math.degrees(math.asin(float(np.clip(d[1], -1.0, 1.0))))
    return camera_from_degrees(eye, yaw, pitch, 0.0, fov, width, height, near, far)


def orbit_cameras(
    center,
    radius: float,
    n: int,
    elevation: float = 20.0,
    fov: float = 45.0,
    width: int = 320,
    height: int = 240,
    near: float = 0.01,
    far: float = 1e4,
    start: float = 0.0,
) -> Camera:
    """``n`` cameras evenly spaced on a horizontal circle around ``center``.

    Returns:
        A batched :class:`Camera` whose leaves have a leading axis of size n,
        ready for ``jax.vmap``.
    """
    n = check_int("n", n, low=1)
    if not radius > 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    c = np.asarray(center, np.float64)
    cams = []
    for k in range(n):
        a = math.radians(start) + 2 * math.pi * k / n
        el = math.radians(elevation)
        eye = c + radius * np.array(
            [math.sin(a) * math.cos(el), math.sin(el), math.cos(a) * math.cos(el)]
        )
        cams.append(look_at(eye, c, fov, width, height, near, far))
    return stack_cameras(cams)


def stack_cameras(cams) -> Camera:
    """Stacks cameras of equal resolution into one batched camera."""
    cams = list(cams)
    if not cams:
        raise ValueError("stack_cameras: need at least one camera")
    shapes = {(c.width, c.height, c.pixel_aspect) for c in cams}
    if len(shapes) != 1:
        raise ValueError(
            f"stack_cameras: cameras differ in (width, height, pixel_aspect) {sorted(shapes)}"
        )
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *cams)


def frame_points(
    points,
    view=(0.0, 0.35, 1.0),
    fov: float = 45.0,
    width: int = 640,
    height: int = 480,
    *,
    margin: float = 0.05,
    half_size: float = 0.0,
) -> Camera:
    """The camera looking along ``-view`` nearest to a subject that still shows all of it.

    The view direction and the field of view are given; the eye is placed so that every
    point projects inside the frame with ``margin`` of the frame left free on each side,
    and the subject is centred where the fit leaves room.  The fit is exact for a
    perspective camera, not a bounding sphere's approximation: with
    ``(r, u, f)`` the camera basis and ``t = tan(fov_x / 2) (1 - 2 margin)``, a point
    ``p`` lies inside horizontally when ``|p.r - a| <= t (p.f - c)`` for the eye
    ``a r + b u + c f``; the nearest ``c`` meeting both sides for every point is
    ``c = -(A+ + A-) / (2 t)`` with ``A+- = max(+-p.r - t p.f)``, and ``a = (A+ - A-) / 2``
    centres the subject; the same holds vertically, and the eye takes the smaller ``c``.

    Args:
        points: (N, 3) world points of the subject (a mesh's vertices, voxel centres).
        view: (3,) direction from the subject towards the eye, any length; y up.
        fov: vertical field of view in degrees, in (0, 180).
        width: image width in pixels.
        height: image height in pixels.
        margin: share of the frame's width and height left free on each side, in
            [0, 0.45].
        half_size: each point stands for an axis-aligned cube of this half edge (0.5 for
            unit voxels at their centres); the whole cube is framed.

    Returns:
        A validated :class:`Camera` (no roll) whose near and far planes bracket the
        subject (near half its nearest depth, far twice its farthest).

    Raises:
        ValueError: no points, non-finite points, ``view`` of zero length, ``fov``
            outside (0, 180) degrees (e.g. radians passed by mistake: ``fov`` < 1 is
            refused as implausible), or ``margin`` outside [0, 0.45].
    """
    width = check_int("width", width, low=1)
    height = check_int("height", height, low=1)
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0:
        raise ValueError("frame_points: points is empty; there is nothing to frame")
    if not np.all(np.isfinite(p)):
        raise ValueError("frame_points: points must be finite")
    if not (isinstance(fov, (int, float, np.integer, np.floating)) and 1.0 <= fov < 180.0):
        raise ValueError(
            f"frame_points: fov is the vertical field of view in degrees, in [1, 180), got "
            f"{fov!r}" + (" (radians? pass degrees)" if 0 < float(fov) < 1.0 else "")
        )
    if not 0.0 <= margin <= 0.45:
        raise ValueError(f"frame_points: margin must be in [0, 0.45], got {margin}")
    if not (math.isfinite(half_size) and half_size >= 0):
        raise ValueError(f"frame_points: half_size must be finite and >= 0, got {half_size}")
    v = np.asarray(view, np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        raise ValueError(f"frame_points: view must be a non-zero finite 3-vector, got {view!r}")
    v = v / np.linalg.norm(v)
    # The orientation of a camera looking along -view (look_at's yaw and pitch).
    yaw = math.degrees(math.atan2(-v[0], -v[2])) if np.hypot(v[0], v[2]) > 1e-12 else 0.0
    pitch = math.degrees(math.asin(float(np.clip(-v[1], -1.0, 1.0))))
    probe = camera_from_degrees(np.zeros(3), yaw, pitch, 0.0, fov, width, height)
    right, up, forward = (np.asarray(b, np.float64) for b in camera_basis(probe))
    shrink = 1.0 - 2.0 * margin
    ty = math.tan(math.radians(fov) / 2) * shrink
    tx = ty * width / height
    pr, pu, pf = p @ right, p @ up, p @ forward

    def reach(w: np.ndarray) -> float:
        # max over each point's cube of the linear function w: centre value + h |w|_1
        return float(half_size * np.abs(w).sum())

    def fit(ps: np.ndarray, axis: np.ndarray, t: float) -> tuple[float, float]:
        hi = float(np.max(ps - t * pf) + reach(axis - t * forward))
        lo = float(np.max(-ps - t * pf) + reach(-axis - t * forward))
        return -(hi + lo) / (2.0 * t), (hi - lo) / 2.0

    cx, a = fit(pr, right, tx)
    cy, b = fit(pu, up, ty)
    extent = float(np.linalg.norm(p.max(0) - p.min(0))) + 2.0 * math.sqrt(3.0) * half_size
    scale = max(extent, 1e-6)
    near_f = float(np.min(pf)) - half_size * np.abs(forward).sum()
    # A subject with no extent across the view puts the eye on it: keep a little distance.
    c = min(cx, cy, near_f - 0.01 * scale)
    eye = a * right + b * up + c * forward
    depth_lo = max(near_f - c, 1e-6 * scale)
    depth_hi = float(np.max(pf)) + half_size * np.abs(forward).sum() - c
    return camera_from_degrees(
        eye, yaw, pitch, 0.0, fov, width, height, 0.5 * depth_lo, 2.0 * depth_hi + 1e-6 * scale
    )
