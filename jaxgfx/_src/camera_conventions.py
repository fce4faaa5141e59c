"""Cameras of other conventions: OpenCV/COLMAP ``K, [R|t]`` and OpenGL/NeRF camera-to-world.

Both convert exactly (float64 on the host, one rounding to the camera's float32): a
world point ``X`` is seen at ``K (R X + t)`` by :func:`camera_from_opencv`'s camera, as
OpenCV and COLMAP see it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, intrinsics_matrix, validate_camera
from jaxgfx._src.checks import check_pixels
from jaxgfx._src.rotation import quaternion_of_matrix, rotation_matrix

__all__ = ["camera_from_opencv", "opencv_from_camera", "camera_from_c2w", "c2w_from_camera"]


def _matrix_arg(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    m = np.asarray(value, np.float64)
    if m.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name} must be finite")
    return m


def _intrinsics_arg(K) -> tuple[np.ndarray, np.ndarray]:
    K = _matrix_arg("K", K, (3, 3))
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]) or np.any(K[1:, :1] != 0) or K[2, 1] != 0:
        raise ValueError(
            f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {K.tolist()}"
        )
    if K[2, 2] != 1:
        raise ValueError(f"K[2, 2] must be 1, got {K[2, 2]}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K's focal lengths must be > 0, got fx={K[0, 0]}, fy={K[1, 1]}")
    return np.array([K[0, 0], K[1, 1]]), np.array([K[0, 2], K[1, 2]])


def _rotation_arg(name: str, R) -> np.ndarray:
    R = _matrix_arg(name, R, (3, 3))
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        raise ValueError(f"{name} must be a rotation matrix (orthonormal, det +1)")
    return R


def camera_from_opencv(
    K, R, t, width: int, height: int, *, near: float = 0.05, far: float = 1e4
) -> Camera:
    """The camera of OpenCV/COLMAP intrinsics ``K`` and world-to-camera pose ``[R|t]``.

    A world point ``X`` is seen at ``K (R X + t)`` (homogeneous pixels, OpenCV's y down):
    the pixel :func:`project` gives for the same point.  Pixel coordinates count from
    the image's top-left corner with centres at ``+0.5`` (COLMAP's and open3d's
    convention), so ``cx = width / 2`` is a centred camera.  OpenCV's own calibrations put
    the first pixel's centre at 0: add 0.5 to their ``cx`` and ``cy``.

    Args:
        K: (3, 3) intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels.
        R: (3, 3) world-to-camera rotation (COLMAP's ``qvec`` as a matrix).
        t: (3,) world-to-camera translation; the eye is at ``-R^T t``.
        width: image width in pixels.
        height: image height in pixels.
        near: near plane distance.
        far: far plane distance.

    Raises:
        ValueError: bad shapes, a skewed ``K``, an ``R`` that is no rotation.
    """
    width, height = check_pixels(width, height)
    focal, principal = _intrinsics_arg(K)
    R = _rotation_arg("R", R)
    t = _matrix_arg("t", t, (3,))
    cam = Camera(
        position=jnp.asarray(-R.T @ t, jnp.float32),
        rotation=jnp.asarray(quaternion_of_matrix(R.T, np), jnp.float32),
        focal=jnp.asarray(focal, jnp.float32),
        principal=jnp.asarray(principal, jnp.float32),
        near=jnp.asarray(near, jnp.float32),
        far=jnp.asarray(far, jnp.float32),
        width=width,
        height=height,
    )
    return validate_camera(cam)


def opencv_from_camera(cam: Camera) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(K (3, 3), R (3, 3), t (3,))`` of a camera in OpenCV's convention.

    Inverse of :func:`camera_from_opencv`; differentiable.
    """
    R = jnp.swapaxes(rotation_matrix(cam.rotation), -1, -2)
    return intrinsics_matrix(cam), R, -(R @ cam.position)


_GL_FROM_CV = np.diag([1.0, -1.0, -1.0])


def camera_from_c2w(
    c2w, K, width: int, height: int, *, near: float = 0.05, far: float = 1e4
) -> Camera:
    """The camera of a 4x4 camera-to-world matrix in the OpenGL/NeRF convention.

    The columns of ``c2w[:3, :3]`` are the camera's right, up and backward axes in the
    world (NeRF's ``transform_matrix`` in ``transforms.json``) and ``c2w[:3, 3]`` is the
    eye.  For a ``transforms.json`` with ``camera_angle_x``, ``K`` has
    ``fx = fy = width / (2 tan(camera_angle_x / 2))`` and the centre as principal point.

    Args:
        c2w: (4, 4) or (3, 4) camera-to-world matrix.
        K: (3, 3) OpenCV intrinsics in pixels (see :func:`camera_from_opencv`).
        width: image width in pixels.
        height: image height in pixels.
        near: near plane distance.
        far: far plane distance.

    Raises:
        ValueError: bad shapes, a skewed ``K``, a rotation part that is no rotation.
    """
    m = np.asarray(c2w, np.float64)
    if m.shape not in ((4, 4), (3, 4)):
        raise ValueError(f"c2w must have shape (4, 4) or (3, 4), got {m.shape}")
    m = _matrix_arg("c2w", m, m.shape)
    rot = _rotation_arg("c2w[:3, :3]", m[:3, :3]) @ _GL_FROM_CV
    return camera_from_opencv(K, rot.T, -rot.T @ m[:3, 3], width, height, near=near, far=far)


def c2w_from_camera(cam: Camera) -> jax.Array:
    """The 4x4 OpenGL/NeRF camera-to-world matrix of a camera.

    Inverse of :func:`camera_from_c2w`; differentiable.
    """
    rot = rotation_matrix(cam.rotation) * jnp.asarray([1.0, -1.0, -1.0], jnp.float32)
    top = jnp.concatenate([rot, jnp.asarray(cam.position)[..., :, None]], axis=-1)
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], top.dtype), top.shape[:-2] + (1, 4))
    return jnp.concatenate([top, bottom], axis=-2)
