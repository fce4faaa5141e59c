"""Framing: the nearest camera along a view direction that shows a whole subject."""

from __future__ import annotations

import math

import numpy as np

from jaxgfx._src.camera import Camera, camera_basis, camera_from_degrees
from jaxgfx._src.checks import check_int

__all__ = ["frame_points"]


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
