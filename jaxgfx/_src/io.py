"""File input and output: meshes via trimesh, PNG via imageio, all writes atomic."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = [
    "atomic_write",
    "load_mesh",
    "up_rotation",
    "mesh_arrays",
    "mesh_texture",
    "save_png",
    "save_npy",
    "save_json",
    "save_mesh",
]

MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off")
UP_AXES = ("x", "y", "z")
"""The axes a mesh file may call "up"; jaxgfx scenes are y-up."""


@contextlib.contextmanager
def atomic_write(path):
    """Yields a temporary path beside ``path``; renames it onto ``path`` on success.

    Readers never see a half-written file: either the old file or the complete
    new one.  On an exception the temporary file is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent
    )
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp creates 0600 files; give the result the usual umask-based mode.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def up_rotation(up: str = "y") -> np.ndarray:
    """The rotation (3, 3) that turns a file's ``up`` axis (``'x'``, ``'y'``, ``'z'``) into +y.

    A proper rotation (determinant +1, so faces keep their winding): z-up ``(x, y, z)`` becomes
    ``(x, z, -y)``, x-up becomes ``(-y, x, z)``, y-up is the identity.  Apply it to vertices as
    ``v @ R.T`` (and to normals the same way).

    Raises:
        ValueError: ``up`` is not one of ``"x"``, ``"y"``, ``"z"``.
    """
    if up not in UP_AXES:
        raise ValueError(f"up must be one of {UP_AXES}, got {up!r}")
    rows = {
        "x": [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
        "y": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        "z": [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
    }
    return np.asarray(rows[up])


def load_mesh(path, up: str = "y"):
    """Loads a triangle mesh (PLY/OBJ/GLB/GLTF/STL/OFF) with trimesh.

    Scenes (e.g. GLB) are flattened into one mesh with their node transforms.

    Args:
        path: the mesh file.
        up: the file's up axis; the mesh is rotated by :func:`up_rotation` so that it points
            along +y (scanned meshes such as Stanford Lucy are z-up).

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unknown suffix or ``up``, a directory, the file cannot be parsed, it has
            no faces (a point cloud is named as one), or a binary PLY ends before the
            vertices and faces its header declares (named as truncated).
    """
    import trimesh

    rot = up_rotation(up)  # checked before reading a possibly large file
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"mesh file {path} is a directory, expected a file")
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(
            f"mesh file {path} has unsupported suffix {path.suffix!r}; use one of {MESH_SUFFIXES}"
        )
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for broken files
        _raise_if_truncated(path)
        raise ValueError(f"mesh file {path} is malformed: {type(exc).__name__}: {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh):
        raise ValueError(f"mesh file {path} holds no triangle mesh (got {type(loaded).__name__})")
    if len(loaded.faces) == 0 or len(loaded.vertices) == 0:
        _raise_if_truncated(path)  # trimesh drops the elements a cut file lacks
    if len(loaded.faces) == 0 and _point_count(path):
        raise ValueError(
            f"mesh file {path} holds {_point_count(path)} points and no faces: a point "
            "cloud, not a triangle mesh"
        )
    if len(loaded.faces) == 0 or len(loaded.vertices) == 0:
        raise ValueError(
            f"mesh file {path} is empty: {len(loaded.vertices)} vertices, {len(loaded.faces)} faces"
        )
    if not np.all(np.isfinite(loaded.vertices)):
        raise ValueError(f"mesh file {path} has non-finite vertex coordinates")
    if up != "y":
        transform = np.eye(4)
        transform[:3, :3] = rot
        loaded.apply_transform(transform)
    return loaded


_PLY_TYPES = {
    **dict.fromkeys(("char", "int8", "uchar", "uint8"), 1),
    **dict.fromkeys(("short", "int16", "ushort", "uint16"), 2),
    **dict.fromkeys(("int", "int32", "uint", "uint32", "float", "float32"), 4),
    **dict.fromkeys(("double", "float64"), 8),
}
_PLY_COUNT_TYPES = {1: "u1", 2: "u2", 4: "u4"}


def _raise_if_truncated(path: Path) -> None:
    """Raises ``ValueError`` if ``path`` is a binary PLY shorter than its header declares.

    trimesh reports such a file as "unexpected length" or, cut between two elements, reads
    the elements that are there (vertices without faces), which would be named an empty
    mesh or a point cloud.  The header says how many rows each element has; the rows of
    fixed size give the expected length at once, those with lists (faces) are walked.
    """
    if path.suffix.lower() != ".ply":
        return
    data = path.read_bytes()
    header = _ply_header(data)
    if header is None:
        return
    fmt, elements, start = header
    endian = "<" if fmt == "binary_little_endian" else ">"
    pos, complete = start, []
    for name, count, props in elements:
        rows, pos = _ply_rows(data, pos, count, props, endian)
        complete.append((name, rows, count))
        if rows < count:
            break
    if all(rows == count for _, rows, count in complete) and len(complete) == len(elements):
        return
    declared = " and ".join(f"{count} {_plural(name)}" for name, count, _ in elements)
    found = ", ".join(f"{rows} of {count} {_plural(name)}" for name, rows, count in complete)
    raise ValueError(
        f"mesh file {path} is truncated: its header declares {declared}, but the file ends "
        f"early, after {len(data)} bytes ({found} complete)"
    )


def _plural(name: str) -> str:
    return {"vertex": "vertices", "face": "faces"}.get(name, f"{name} rows")


def _ply_header(data: bytes):
    """``(format, [(element, count, [(kind, sizes)])], data start)`` of a binary PLY, else None.

    ``kind`` is ``"scalar"`` with ``sizes = item bytes`` or ``"list"`` with
    ``sizes = (count bytes, item bytes)``.
    """
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        return None
    start = data.find(b"\n", end) + 1
    if start == 0:
        return None
    fmt: str | None = None
    elements: list[tuple[str, int, list]] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines():
        words = line.split()
        try:
            if words[:1] == ["format"]:
                fmt = words[1]
            elif words[:1] == ["element"]:
                elements.append((words[1], int(words[2]), []))
            elif words[:2] == ["property", "list"]:
                elements[-1][2].append(("list", (_PLY_TYPES[words[2]], _PLY_TYPES[words[3]])))
            elif words[:1] == ["property"]:
                elements[-1][2].append(("scalar", _PLY_TYPES[words[1]]))
        except (IndexError, KeyError, ValueError):
            return None  # a header trimesh refuses for its own reason
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        return None
    return fmt, elements, start


def _ply_rows(data: bytes, pos: int, count: int, props, endian: str) -> tuple[int, int]:
    """How many of ``count`` rows from byte ``pos`` are complete, and the byte after them."""
    lists = [i for i, (kind, _) in enumerate(props) if kind == "list"]
    if not lists:
        size = sum(sizes for _, sizes in props)
        rows = min(count, (len(data) - pos) // size) if size else count
        return rows, pos + rows * size
    if len(lists) == 1:
        # One list (faces): rows of equal length are the usual case, checked on the counts
        # without a walk.
        i = lists[0]
        n_bytes, item = props[i][1]
        head = sum(sizes for _, sizes in props[:i])
        tail = sum(sizes for _, sizes in props[i + 1 :])
        if pos + head + n_bytes <= len(data):
            dtype = np.dtype(endian + _PLY_COUNT_TYPES[n_bytes])
            n = int(np.frombuffer(data, dtype, 1, pos + head)[0])
            size = head + n_bytes + n * item + tail
            rows = min(count, (len(data) - pos) // size)
            at = pos + head + size * np.arange(rows)
            counts = np.frombuffer(data, np.uint8)[at[:, None] + np.arange(n_bytes)]
            if np.all(counts == counts[:1]):
                return rows, pos + rows * size
    for row in range(count):  # lists of different lengths: walk them
        for kind, sizes in props:
            if kind == "scalar":
                pos += sizes
                continue
            n_bytes, item = sizes
            if pos + n_bytes > len(data):
                return row, len(data) + 1
            n = int(np.frombuffer(data, np.dtype(endian + _PLY_COUNT_TYPES[n_bytes]), 1, pos)[0])
            pos += n_bytes + n * item
        if pos > len(data):
            return row, pos
    return count, pos


def _point_count(path: Path) -> int:
    """Vertices of a file that trimesh reads as a point cloud (no faces), else 0."""
    import trimesh

    try:
        cloud = trimesh.load(path, process=False)
    except Exception:
        return 0
    return len(cloud.vertices) if isinstance(cloud, trimesh.PointCloud) else 0


def mesh_arrays(mesh, default_color=(0.75, 0.72, 0.68)):
    """(vertices (V,3) float32, faces (F,3) int32, colours (V,3) float32) of a trimesh."""
    v = np.asarray(mesh.vertices, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    colors = None
    visual = getattr(mesh, "visual", None)
    if visual is not None and getattr(visual, "kind", None) == "vertex":
        vc = np.asarray(visual.vertex_colors)
        if vc.shape[0] == len(v):
            colors = vc[:, :3].astype(np.float32) / 255.0
    if colors is None:
        colors = np.broadcast_to(np.asarray(default_color, np.float32), v.shape).copy()
    return v, f, colors


def mesh_texture(mesh) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(uvs (V, 2) float32, image (H, W, C) uint8)`` of a textured trimesh, or Nones.

    trimesh reads OBJ (``map_Kd``) and glTF (``baseColorTexture``) textures with v counting
    upwards; the UVs here count from the image's top-left corner, as
    :func:`jaxgfx.raster.texture` reads them (``v`` flipped).
    """
    visual = getattr(mesh, "visual", None)
    if visual is None or getattr(visual, "kind", None) != "texture":
        return None, None
    uv = getattr(visual, "uv", None)
    material = getattr(visual, "material", None)
    image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
    if uv is None or image is None or len(uv) != len(mesh.vertices):
        return None, None
    pixels = np.asarray(image.convert("RGBA") if hasattr(image, "convert") else image)
    uvs = np.asarray(uv, np.float32).copy()
    uvs[:, 1] = 1.0 - uvs[:, 1]
    return uvs, pixels.astype(np.uint8)


def _as_uint8_image(img) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[-1] not in (3, 4)):
        raise ValueError(f"image must be (H, W), (H, W, 3) or (H, W, 4), got {a.shape}")
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"image must be non-empty, got {a.shape}")
    if a.dtype == np.uint8:
        return a
    if not np.issubdtype(a.dtype, np.floating):
        raise TypeError(f"image must be uint8 or float in [0, 1], got {a.dtype}")
    if not np.all(np.isfinite(a)):
        raise ValueError("image has non-finite values")
    return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def save_png(path, img) -> Path:
    """Writes an image (uint8, or float in [0, 1]) as PNG, atomically."""
    import imageio.v3 as iio

    data = _as_uint8_image(img)
    path = Path(path)
    with atomic_write(path) as tmp:
        iio.imwrite(tmp, data, extension=".png")
    return path


def save_npy(path, arr) -> Path:
    """Writes a NumPy array atomically."""
    path = Path(path)
    with atomic_write(path) as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, np.asarray(arr))
    return path


def save_json(path, obj) -> Path:
    """Writes JSON atomically."""
    path = Path(path)
    with atomic_write(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, default=float) + "\n")
    return path


def save_mesh(path, vertices, faces, colors=None) -> Path:
    """Exports a mesh via trimesh (format from the suffix: .ply, .glb, .obj, .stl), atomically."""
    import trimesh

    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in ("ply", "glb", "obj", "stl", "off"):
        raise ValueError(f"save_mesh: unsupported suffix {path.suffix!r}")
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    vertex_colors = None
    if colors is not None:
        vertex_colors = np.asarray(colors)
        if vertex_colors.dtype != np.uint8:
            vertex_colors = (np.clip(vertex_colors, 0, 1) * 255 + 0.5).astype(np.uint8)
    mesh = trimesh.Trimesh(v, f, process=False, vertex_colors=vertex_colors)
    data = mesh.export(file_type=fmt)
    if isinstance(data, str):
        data = data.encode()
    with atomic_write(path) as tmp:
        tmp.write_bytes(data)
    return path
