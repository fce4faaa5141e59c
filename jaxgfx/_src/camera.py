"""One pinhole camera shared by every render pass (thesis 2.3).

All passes (background, terrain, static objects, characters) use identical
view-point, orientation, field of view and resolution so their depth buffers
can be merged per pixel (thesis 2.4.2, Fig. 2.3).

Conventions (used by every module of jaxgfx):

* World: right-handed, **y up**, x-z is the ground plane.
* Camera space: ``x`` right, ``y`` up, ``z`` forward (distance along the view
  axis).  *Depth* everywhere in jaxgfx means camera-space ``z``.
* Screen: pixel ``(i, j)`` = (column, row), row 0 at the top, pixel centres
  at ``(i + 0.5, j + 0.5)``.  A camera-space point ``(x, y, z)`` lands at
  ``(cx + fx x / z, cy - fy y / z)``: ``(fx, fy)`` are the focal lengths in
  pixels and ``(cx, cy)`` the principal point, as in an OpenCV intrinsics
  matrix ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (OpenCV's camera ``y``
  points down; jaxgfx's points up, hence the minus).
* Orientation: a quaternion ``(w, x, y, z)`` of any non-zero length, the
  rotation from OpenCV camera axes (right, down, forward) to the world.  It is
  normalised where it is used, so a gradient step on it never leaves the set
  of rotations and no orientation is singular (Euler angles lock at a pitch of
  +-90 degrees).  :func:`camera_from_degrees` and :func:`yaw_pitch_roll_rotation`
  build it from yaw/pitch/roll: ``yaw`` rotates about +y (0 looks along +z,
  positive turns the view towards +x), ``pitch`` is positive looking up,
  ``roll`` turns the image clockwise about the view axis.
* Other conventions convert exactly: :func:`camera_from_opencv` /
  :func:`opencv_from_camera` (``K`` and world-to-camera ``[R|t]``, COLMAP's),
  :func:`camera_from_c2w` / :func:`c2w_from_camera` (4x4 camera-to-world in
  the OpenGL convention of NeRF's ``transforms.json``: x right, y up, z back).
* :func:`supersampled` renders the same view on a finer grid for
  anti-aliasing (the thesis's 2x1 AA uses pixels half as wide, 4.5.6.2).
"""

from __future__ import annotations

import dataclasses
import functools
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
from jaxgfx._src.eager import compiled_when_eager
from jaxgfx._src.rotation import quaternion_of_angles, rotation_matrix

__all__ = [
    "Camera",
    "camera_from_degrees",
    "intrinsics_matrix",
    "look_at",
    "orbit_cameras",
    "yaw_pitch_roll",
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
    "MAX_PIXELS",
]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Camera:
    """Pinhole camera.  Array fields are pytree leaves; the resolution is static.

    Build one with :func:`camera_from_degrees`, :func:`look_at`, :func:`frame_points`,
    :func:`camera_from_opencv` or :func:`camera_from_c2w`; every field is a leaf that
    ``grad`` and ``vmap`` see (a pose, a focal length or a principal point can be fitted).

    Attributes:
        position: (3,) float32 world position of the eye.
        rotation: (4,) quaternion ``(w, x, y, z)``, any non-zero length: the rotation
            from OpenCV camera axes (right, down, forward) to the world.
        focal: (2,) ``(fx, fy)`` focal lengths in pixels, > 0.
        principal: (2,) ``(cx, cy)`` principal point in pixels from the image's top-left
            corner (``(width / 2, height / 2)`` for a centred one).
        near: () near clipping distance along the view axis, > 0.
        far: () far clipping distance, > near.
        width: static int, image width in pixels.
        height: static int, image height in pixels.
    """

    position: jax.Array
    rotation: jax.Array
    focal: jax.Array
    principal: jax.Array
    near: jax.Array
    far: jax.Array
    width: int = static_field(640)
    height: int = static_field(480)

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

    @property
    def fov_y(self) -> jax.Array:
        """Vertical field of view in radians, ``2 atan(height / (2 fy))``."""
        return 2.0 * jnp.arctan(0.5 * self.height / jnp.asarray(self.focal)[..., 1])

    @property
    def pixel_aspect(self) -> jax.Array:
        """Pixel width / pixel height, ``fy / fx`` (0.5 in the thesis's 2x1 AA frame)."""
        f = jnp.asarray(self.focal)
        return f[..., 1] / f[..., 0]

    @property
    def yaw(self) -> jax.Array:
        """Radians about +y (see :func:`yaw_pitch_roll`)."""
        return yaw_pitch_roll(self)[0]

    @property
    def pitch(self) -> jax.Array:
        """Radians, positive looking up (see :func:`yaw_pitch_roll`)."""
        return yaw_pitch_roll(self)[1]

    @property
    def roll(self) -> jax.Array:
        """Radians about the view axis (see :func:`yaw_pitch_roll`)."""
        return yaw_pitch_roll(self)[2]


_FLOAT_FIELDS = ("position", "rotation", "focal", "principal", "near", "far")
_VECTOR_SIZES = {"position": 3, "rotation": 4, "focal": 2, "principal": 2}


def as_float32(cam: Camera) -> Camera:
    """``cam`` with every float field as float32 (the kernels' precision, also under x64)."""
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), cam)


def validate_camera(cam: Camera, *, where: str | None = None) -> Camera:
    """Checks a camera; raises ``TypeError``/``ValueError`` naming the field.

    Types, shapes and the resolution are checked on abstract values too, so the checks
    hold inside ``jit``; values (finite, ``focal > 0``, a non-zero ``rotation``,
    ``0 < near < far``) where they are concrete, and for traced cameras inside
    :func:`~jaxgfx.checks.checked` while the program runs.  A batched camera (leading
    axes, :func:`stack_cameras`) is accepted.

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
        size = _VECTOR_SIZES.get(name)
        if size is not None and (len(shape) < 1 or shape[-1] != size):
            raise ValueError(f"camera {name} must have shape ({size},), got {shape}")
        if isinstance(value, jax.core.Tracer):
            continue
        arr = np.asarray(value)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"camera {name} must be finite, got {arr}")
    if not isinstance(cam.focal, jax.core.Tracer):
        focal = np.asarray(cam.focal)
        if np.any(focal <= 0):
            raise ValueError(f"camera focal (fx, fy) must be > 0 pixels, got {focal}")
    if not isinstance(cam.rotation, jax.core.Tracer):
        norm = np.linalg.norm(np.asarray(cam.rotation, np.float64), axis=-1)
        if np.any(norm < 1e-6):
            raise ValueError(
                f"camera rotation must be a non-zero quaternion (w, x, y, z), got norm {norm}"
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
    focal = jnp.asarray(cam.focal)
    require_values("cam.focal", focal > 0, focal, "{} must be > 0", where)
    q = jnp.asarray(cam.rotation)
    norm = jnp.sqrt(jnp.sum(q * q, axis=-1))
    require_values("cam.rotation", norm >= 1e-6, norm, "has norm {}, not a rotation", where)
    near, far = jnp.asarray(cam.near), jnp.asarray(cam.far)
    require_values("cam.near", near > 0, near, "{} must be > 0", where)
    require_values("cam.far", far > near, far, "{} must be > near", where)


def yaw_pitch_roll(cam: Camera) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The camera's yaw, pitch and roll in radians (inverse of :func:`yaw_pitch_roll_rotation`).

    Looking straight up or down, yaw and roll are not separable; yaw is then 0.  Works on a
    batched camera (each angle has the batch's shape).
    """
    right, up, forward = camera_basis(cam)
    level = jnp.hypot(forward[..., 0], forward[..., 2]) > 1e-6
    pitch = jnp.arcsin(jnp.clip(forward[..., 1], -1.0, 1.0))
    yaw = jnp.where(level, jnp.arctan2(forward[..., 0], forward[..., 2]), 0.0)
    # Straight up or down the roll is the image's turn from yaw 0: read it from right.
    roll_level = jnp.arctan2(-right[..., 1], up[..., 1])
    roll_vertical = jnp.arctan2(-right[..., 2], -right[..., 0]) * jnp.sign(forward[..., 1])
    roll = jnp.where(level, roll_level, roll_vertical)
    return yaw, pitch, roll


def camera_basis(cam: Camera) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Right, up and forward unit vectors of the camera in world space.

    Columns of :func:`rotation_matrix` of ``cam.rotation`` (up is minus OpenCV's down):
    finite and smooth for every orientation, straight up and down included.

    Returns:
        ``(right, up, forward)``, each (3,) (or the camera's batch shape + (3,)).
    """
    m = rotation_matrix(cam.rotation)
    return m[..., 0], -m[..., 1], m[..., 2]


def focal_length(cam: Camera) -> jax.Array:
    """Vertical focal length in pixels, ``fy`` (``(height / 2) / tan(fov_y / 2)``)."""
    return jnp.asarray(cam.focal)[..., 1]


def focal_lengths(cam: Camera) -> tuple[jax.Array, jax.Array]:
    """Horizontal and vertical focal lengths in pixels, ``(fx, fy)``."""
    f = jnp.asarray(cam.focal)
    return f[..., 0], f[..., 1]


def _principal(cam: Camera) -> tuple[jax.Array, jax.Array]:
    c = jnp.asarray(cam.principal)
    return c[..., 0], c[..., 1]


def intrinsics_matrix(cam: Camera) -> jax.Array:
    """The OpenCV intrinsics ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (3, 3)."""
    fx, fy = focal_lengths(cam)
    cx, cy = _principal(cam)
    zero, one = jnp.zeros_like(fx), jnp.ones_like(fx)
    return jnp.stack(
        [jnp.stack([fx, zero, cx]), jnp.stack([zero, fy, cy]), jnp.stack([zero, zero, one])]
    )


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
    *,
    principal=None,
) -> Camera:
    """Builds a validated :class:`Camera` from angles in degrees.

    Args:
        position: (3,) eye position, y up.
        yaw: degrees about +y, 0 looks along +z.
        pitch: degrees, positive looks up.
        roll: degrees about the view axis.
        fov: vertical field of view in degrees; pixels are square (``fx = fy``).
        width: image width in pixels.
        height: image height in pixels.
        near: near plane distance.
        far: far plane distance.
        principal: (2,) principal point ``(cx, cy)`` in pixels; the image centre if None.
    """
    width, height = check_pixels(width, height)
    fov = check_float("fov", fov)
    if not 0.0 < fov < 180.0:
        raise ValueError(f"fov must be in (0, 180) degrees, got {fov}")
    pos = np.asarray(position, dtype=np.float32)
    if pos.shape != (3,):
        raise ValueError(f"position must have shape (3,), got {pos.shape}")
    f = 0.5 * height / math.tan(math.radians(fov) / 2)
    # float64 NumPy: the constructor rounds once, to float32, and compiles nothing.
    y, p, r = (
        np.float64(math.radians(check_float(n, v)))
        for n, v in (("yaw", yaw), ("pitch", pitch), ("roll", roll))
    )
    q = quaternion_of_angles(y, p, r, np)
    cam = Camera(
        position=jnp.asarray(pos),
        rotation=jnp.asarray(q, jnp.float32),
        focal=jnp.asarray([f, f], jnp.float32),
        principal=_principal_arg(principal, width, height),
        near=jnp.asarray(near, jnp.float32),
        far=jnp.asarray(far, jnp.float32),
        width=width,
        height=height,
    )
    return validate_camera(cam)


def _principal_arg(principal, width: int, height: int) -> jax.Array:
    if principal is None:
        return jnp.asarray([0.5 * width, 0.5 * height], jnp.float32)
    c = np.asarray(principal, np.float64)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ValueError(f"principal must be a finite (cx, cy) pair, got {principal!r}")
    return jnp.asarray(c, jnp.float32)


def supersampled(cam: Camera, factor: tuple[int, int]) -> Camera:
    """The same view on a grid ``factor = (sx, sy)`` times finer (anti-aliasing).

    The frame is ``sx W x sy H`` pixels of ``1 / sx`` by ``1 / sy`` of the original
    pixel (focal lengths and principal point scaled alike), so
    :func:`jaxgfx.post.antialias` with the same factor gives back a ``W x H`` image of
    the original view.  ``(2, 1)`` is the thesis's 2x1 AA (pixels half as wide,
    4.5.6.2), ``(2, 2)`` 2x2 AA.
    """
    try:
        sx, sy = (int(v) for v in factor)
    except (TypeError, ValueError):
        raise TypeError(f"factor must be a pair of ints, got {factor!r}") from None
    if sx < 1 or sy < 1:
        raise ValueError(f"factor must be positive, got {factor}")
    scale = jnp.asarray([sx, sy], jnp.float32)
    return validate_camera(
        dataclasses.replace(
            cam,
            width=cam.width * sx,
            height=cam.height * sy,
            focal=jnp.asarray(cam.focal) * scale,
            principal=jnp.asarray(cam.principal) * scale,
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
    cx, cy = _principal(cam)
    z = p_cam[..., 2]
    safe_z = jnp.where(jnp.abs(z) > 1e-12, z, 1e-12)
    sx = cx + fx * p_cam[..., 0] / safe_z
    sy = cy - fy * p_cam[..., 1] / safe_z
    return jnp.stack([sx, sy], axis=-1)


def screen_to_camera(cam: Camera, sx, sy) -> tuple[jax.Array, jax.Array]:
    """Inverse of :func:`camera_to_screen` at depth 1.

    Screen x coordinates ``sx`` and y coordinates ``sy`` (any shapes, not
    broadcast against each other) map to the camera-space ``x / z`` and
    ``y / z`` of their rays.  Every pixel-ray construction uses this, so
    the intrinsics are honoured in one place.
    """
    fx, fy = focal_lengths(cam)
    cx, cy = _principal(cam)
    # One reciprocal, multiplied: XLA rewrites a division by a broadcast value so in
    # some programs (a vmapped batch of cameras) and not in others, and the rays'
    # last bits would then depend on the program.
    return (sx - cx) * (1.0 / fx), (cy - sy) * (1.0 / fy)


@compiled_when_eager
def project(cam: Camera, points: jax.Array) -> tuple[jax.Array, jax.Array]:
    """World points (..., 3) -> (pixel xy (..., 2), depth (...)).

    Depth is the camera-space z (distance along the view axis); points behind
    the eye have depth <= 0.
    """
    p = world_to_camera(cam, points)
    return camera_to_screen(cam, p), p[..., 2]


@functools.partial(compiled_when_eager, static_argnames=("normalize",))
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
    """4x4 camera -> clip matrix (OpenGL-style NDC in [-1, 1], y up, z forward).

    ``clip = P @ [x, y, z, 1]``; ``ndc = clip[:3] / clip[3]`` with ``clip[3] = z``; NDC
    x = -1 is the image's left edge and y = +1 its top, for any principal point.
    """
    fx, fy = focal_lengths(cam)
    cx, cy = _principal(cam)
    W, H = float(cam.width), float(cam.height)
    n, fa = cam.near, cam.far
    zero = jnp.zeros_like(fx)
    one = jnp.ones_like(fx)
    return jnp.stack(
        [
            jnp.stack([2.0 * fx / W, zero, (2.0 * cx - W) / W, zero]),
            jnp.stack([zero, 2.0 * fy / H, (H - 2.0 * cy) / H, zero]),
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
    shapes = {(c.width, c.height) for c in cams}
    if len(shapes) != 1:
        raise ValueError(f"stack_cameras: cameras differ in (width, height) {sorted(shapes)}")
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *cams)
