"""Default views and the checks that a frame shows its subject, shared by the subcommands.

Every command that draws a subject without ``--camera`` frames it with
:func:`jaxgfx.camera.frame_points`: the eye looks along a fixed direction per kind of
subject and stands as near as the field of view allows while every point of the subject
(every vertex, every voxel cube) projects inside the frame with :data:`MARGIN` of the
frame free on each side.  After rendering, :func:`warn_if_unseen` tells on stderr when the
frame does not show the subject: nothing drawn, the subject behind the camera, outside
the view, or smaller than a pixel (a field of view near 180 degrees).
"""

from __future__ import annotations

import math
import sys

import numpy as np

__all__ = [
    "MARGIN",
    "MESH_VIEW",
    "CHARACTER_VIEW",
    "ARM_VIEW",
    "VOXEL_VIEW",
    "framed_camera",
    "camera_text",
    "orbit_distance",
    "projected_extent",
    "warn_if_unseen",
]

MARGIN = 0.05
"""Share of the frame's width and height left free on each side of a framed subject."""

MESH_VIEW = (0.0, 0.35, 1.0)
"""Meshes: from the front (+z, where glTF and most scans face) and a little above."""
CHARACTER_VIEW = (0.8, 0.4, 0.6)
"""Skinned glTF characters: three-quarter from the side (their front view hides their length)."""
ARM_VIEW = (1.0, 0.15, 0.0)
"""The demo arm (bone chain along +z): from the side, so the bend shows."""
VOXEL_VIEW = (0.0, math.sin(math.radians(20.0)), math.cos(math.radians(20.0)))
"""Voxel scenes: from their front (+z) and 20 degrees above (``voxelize`` turns a volume's
anatomical front to +z)."""


def framed_camera(points, view, fov: float, size, *, half_size: float = 0.0):
    """:func:`jaxgfx.camera.frame_points` with the CLI's margin; ``size`` is (W, H)."""
    from jaxgfx.camera import frame_points

    w, h = size
    return frame_points(points, view, fov, w, h, margin=MARGIN, half_size=half_size)


def camera_text(cam) -> str:
    """``x,y,z,yaw,pitch`` (degrees) of a camera without roll, as ``--camera`` takes it."""
    x, y, z = (float(v) for v in np.asarray(cam.position))
    yaw, pitch = (math.degrees(float(a)) for a in (cam.yaw, cam.pitch))
    return ",".join(f"{round(v, 4):g}" for v in (x, y, z, yaw, pitch))


def orbit_distance(radius: float, fov: float, size) -> float:
    """Distance from which a sphere of ``radius`` fits the narrower field of view (with
    :data:`MARGIN`) seen from any direction: the orbit of ``jaxgfx sweep``."""
    w, h = size
    half_y = math.radians(fov) / 2
    half = min(half_y, math.atan(math.tan(half_y) * w / h))
    return radius / math.sin(half) / (1.0 - 2.0 * MARGIN)


def projected_extent(cam, points) -> tuple[int, float, tuple[float, float, float, float]]:
    """Where the subject lands in the frame, in NumPy (no JAX computation).

    Args:
        cam: the camera (unbatched).
        points: (N, 3) world points of the subject.

    Returns:
        ``(n_front, size, (x0, y0, x1, y1))``: the points in front of the near plane, the
        larger side in pixels of their screen bounding box, and that box.
    """
    from jaxgfx.camera import camera_basis

    p = np.asarray(points, np.float64).reshape(-1, 3) - np.asarray(cam.position, np.float64)
    r, u, f = (np.asarray(b, np.float64) for b in camera_basis(cam))
    z = p @ f
    front = z > float(cam.near)
    if not front.any():
        return 0, 0.0, (0.0, 0.0, 0.0, 0.0)
    fx, fy = (float(v) for v in np.asarray(cam.focal))
    cx, cy = (float(v) for v in np.asarray(cam.principal))
    sx = cx + fx * (p[front] @ r) / z[front]
    sy = cy - fy * (p[front] @ u) / z[front]
    box = (float(sx.min()), float(sy.min()), float(sx.max()), float(sy.max()))
    return int(front.sum()), max(box[2] - box[0], box[3] - box[1]), box


def warn_if_unseen(
    command: str, cam, points, hit_pixels: int, what: str, *, faces=None, fov=None
) -> bool:
    """Tells on stderr (one line) when a rendered frame does not show its subject.

    Args:
        command: the subcommand, for the ``jaxgfx CMD: warning:`` prefix.
        cam: the camera the frame was rendered with.
        points: (N, 3) world points of the subject.
        hit_pixels: pixels the subject covers in the frame.
        what: the subject in words (``"mesh 'bunny.ply'"``).
        faces: optional (F, 3) triangles of a mesh: all of zero area is named as the cause.
        fov: the ``--fov`` in degrees, named when the subject is sub-pixel.

    Returns:
        True when a warning was printed.
    """
    n_front, size, (x0, y0, x1, y1) = projected_extent(cam, points)
    why = None
    if n_front == 0:
        why = f"the {what} lies behind the camera"
    elif x1 < 0 or y1 < 0 or x0 > cam.width or y0 > cam.height:
        why = f"the {what} lies outside the view"
    elif size < 1.0:
        hint = f" at --fov {fov:g}; a smaller --fov shows it" if fov is not None else ""
        why = f"the {what} spans {size:.2g} pixels{hint}"
    elif hit_pixels == 0:
        why = f"no pixel shows the {what}"
        if faces is not None and _all_degenerate(points, faces):
            why += f": all its {len(faces)} triangles have zero area"
    if why is None:
        return False
    print(f"jaxgfx {command}: warning: the frame is empty: {why}", file=sys.stderr)
    return True


def _all_degenerate(points, faces) -> bool:
    v = np.asarray(points, np.float64)
    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return True
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = np.linalg.norm(np.cross(b - a, c - a), axis=-1)
    scale = max(float(np.ptp(v, axis=0).max()), 1e-30)
    return bool(np.all(area <= 1e-12 * scale * scale))
