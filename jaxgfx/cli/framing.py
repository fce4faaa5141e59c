"""Default views and the checks that a frame shows its subject, shared by the subcommands.

Every command that draws a subject without ``--camera`` frames it with
:func:`jaxgfx.camera.frame_points`: the eye looks along a fixed direction per kind of
subject and stands as near as the field of view allows while every point of the subject
(every vertex, every voxel cube) projects inside the frame with :data:`MARGIN` of the
frame free on each side.  After rendering, :func:`warn_if_unseen` tells on stderr when the
frame does not show the subject: nothing drawn, the subject behind the camera, outside
the view, or smaller than a pixel (a field of view near 180 degrees).

**The front of a mesh or voxel scene** (``render``, ``voxelize``; the views above stand
in front of it): ``--front`` when given; else the front the file's format states, when
it is horizontal once ``--up`` is turned to +y (a glTF asset faces +z; a scanned
volume's face is -y in DICOM and NRRD patient coordinates); else :func:`pick_front`:
among the four horizontal sides +z, +x, -z, -x, the one that the most surface faces
(the area-weighted normals pointing to it, :func:`side_areas`), where a side leads only
by more than :data:`FRONT_TIE` of that area and the order +z, +x, -z, -x decides the
rest.  For a closed surface a side's facing area is its silhouette area, the same from
opposite sides: the broad side is the front and the order picks +z or +x, the front of
y-up (glTF) and z-up (``-y`` turned by ``--up z``) files.  An open scan's scanned side
outweighs its open back and is its front.
"""

from __future__ import annotations

import math
import sys

import numpy as np

__all__ = [
    "MARGIN",
    "FRONT_TIE",
    "SIDES",
    "side_areas",
    "voxel_side_areas",
    "pick_front",
    "turn_view",
    "FRONT_AXES",
    "axis_vector",
    "mesh_front",
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


SIDES = ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (-1.0, 0.0, 0.0))
"""The four horizontal sides a default front is chosen from, in the order ties take."""
FRONT_TIE = 0.02
"""A side leads the default front rule only by more than this share of its facing area:
a scan's small holes and the noise of its triangles do not turn a subject round."""


def side_areas(vertices, faces) -> np.ndarray:
    """Surface area of a mesh facing each of :data:`SIDES`, in y-up world coordinates.

    Each triangle adds ``area * max(0, n . d)`` to side ``d`` (``n`` its unit normal by its
    winding): the area seen projected along ``d``, counted once per layer.  For a closed
    surface it is the silhouette area, the same for opposite sides.

    Args:
        vertices: (V, 3) points, y up.
        faces: (F, 3) vertex indices.

    Returns:
        (4,) float64 areas for +z, +x, -z, -x.

    Raises:
        ValueError: ``vertices`` or ``faces`` of the wrong shape, or a face index out of
            range.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must be (V, 3), got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be (F, 3) integer indices, got {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces must index the {len(v)} vertices, got {f.min()}..{f.max()}")
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = 0.5 * np.cross(b - a, c - a)  # area-weighted normals
    return np.maximum(n @ np.asarray(SIDES).T, 0.0).sum(0)


def voxel_side_areas(coords) -> np.ndarray:
    """Voxel faces facing each of :data:`SIDES`: faces whose neighbour that way is empty.

    Args:
        coords: (N, 3) integer voxel coordinates, y up.

    Returns:
        (4,) float64 face counts for +z, +x, -z, -x.

    Raises:
        ValueError: ``coords`` is not (N, 3).
    """
    c = np.asarray(coords, np.int64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"coords must be (N, 3), got shape {c.shape}")
    if len(c) == 0:
        return np.zeros(4)
    c = c - c.min(0) + 1  # a free layer on every side: a neighbour's key stays unique
    dims = c.max(0) + 2

    def key(p):
        return (p[:, 0] * dims[1] + p[:, 1]) * dims[2] + p[:, 2]

    filled = np.sort(key(c))
    out = []
    for d in np.asarray(SIDES, np.int64):
        k = key(c + d)
        pos = np.minimum(np.searchsorted(filled, k), len(filled) - 1)
        out.append(float(np.count_nonzero(filled[pos] != k)))
    return np.asarray(out)


def pick_front(areas) -> np.ndarray:
    """The default front from :func:`side_areas` or :func:`voxel_side_areas`.

    The first of :data:`SIDES` (+z, +x, -z, -x) whose area is within :data:`FRONT_TIE` of
    the largest.

    Args:
        areas: (4,) non-negative areas for +z, +x, -z, -x.

    Returns:
        (3,) the chosen side, a horizontal unit axis (+z when every area is 0).

    Raises:
        ValueError: ``areas`` is not 4 finite non-negative numbers.
    """
    a = np.asarray(areas, np.float64)
    if a.shape != (4,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"areas must be 4 finite numbers >= 0 (+z, +x, -z, -x), got {areas!r}")
    best = int(np.argmax(a >= (1.0 - FRONT_TIE) * a.max()))
    return np.asarray(SIDES[best])


def turn_view(view, front) -> np.ndarray:
    """A view given for a subject facing +z, turned about y for one facing ``front``.

    Args:
        view: (3,) direction from the subject to the eye when the front is +z.
        front: (3,) horizontal direction of the subject's front (need not be unit).

    Returns:
        (3,) the view for ``front``: its +z part along ``front``, its +x part along
        ``front`` turned a quarter to the right (+x for +z).

    Raises:
        ValueError: ``front`` is not horizontal and non-zero.
    """
    f = np.asarray(front, np.float64)
    if f.shape != (3,) or abs(f[1]) > 1e-9 or np.hypot(f[0], f[2]) == 0:
        raise ValueError(f"front must be a horizontal non-zero 3-vector, got {front!r}")
    f = f / np.hypot(f[0], f[2])
    right = np.array([f[2], 0.0, -f[0]])  # +z -> +x, as seen from the front
    v = np.asarray(view, np.float64)
    return v[0] * right + v[1] * np.array([0.0, 1.0, 0.0]) + v[2] * f


FRONT_AXES = ("x", "y", "z", "-x", "-y", "-z")
"""``--front`` values: the file's axis out of the subject's front."""
GLTF_FRONT = "z"
"""glTF assets face +z (the glTF 2.0 specification), a front their format states."""


def axis_vector(axis: str) -> np.ndarray:
    """``'x'``, ``'-z'``, ... as a (3,) unit vector.

    Raises:
        ValueError: ``axis`` is not one of :data:`FRONT_AXES`.
    """
    if axis not in FRONT_AXES:
        raise ValueError(f"axis must be one of {', '.join(FRONT_AXES)}, got {axis!r}")
    v = np.zeros(3)
    v["xyz".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
    return v


def mesh_front(vertices, faces, *, front: str | None, up: str, path: str = "") -> np.ndarray:
    """The front of a mesh by the rule of this module, in y-up world coordinates.

    Args:
        vertices: (V, 3) world vertices, the file's ``up`` already turned to +y.
        faces: (F, 3) vertex indices.
        front: the ``--front`` axis of the file, or None for the default.
        up: the file's up axis (``x``, ``y``, ``z``), as given to ``--up``.
        path: the file (a ``.glb`` / ``.gltf`` states its front).

    Returns:
        (3,) a horizontal unit axis (+-x or +-z).

    Raises:
        CliError: ``front`` is the ``up`` axis (``--front`` must name a horizontal one).
    """
    from jaxgfx.cli.args import CliError
    from jaxgfx.io import up_rotation

    turn = up_rotation(up)
    if front is not None:
        facing = turn @ axis_vector(front)
        if abs(facing[1]) > 0.5:
            raise CliError(f"--front {front} is the --up axis ({up}); name a horizontal axis")
        return facing
    if str(path).lower().endswith((".glb", ".gltf")):
        facing = turn @ axis_vector(GLTF_FRONT)
        if abs(facing[1]) < 0.5:
            return facing
    return pick_front(side_areas(vertices, faces))


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
