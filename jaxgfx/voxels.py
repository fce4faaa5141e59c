"""Surface voxels and their run-length encoding (thesis 4.3, 4.4.6, 4.4.7).

Inputs (4.3): triangle meshes voxelized by edge interpolation (Eq. 4.1),
scanned volumes with an iso threshold (raw + MetaImage ``.mhd`` / NRRD
``.nhdr`` headers), Voxlap's ``.vxl`` worlds and ``.kv6`` sprites, and
procedural trees (4.3.3).  All of them become a :class:`Voxels` list of
coloured surface voxels.

Pre-processing (4.4.6): each vertical column is run-length encoded from top
to bottom into 16-bit elements of (skipped, drawn) counts (10 + 6 bits, long
runs split).  A pointer map over the x-z plane holds, per column, the pointer
to its remaining elements, its element count and its first element inline
(64 bits per entry, Fig. 4.11).  Mip levels (4.4.7) are 2x down-sampled
copies encoded the same way.  :func:`decode_rle` gives back exactly the
voxels that went in.

Conventions: scene coordinates are voxel units, y up; voxel ``(x, y, z)``
occupies ``[x, x+1) x [y, y+1) x [z, z+1)``.  Everything here is NumPy
pre-processing; :class:`RLEVolume` is the JAX pytree the renderer consumes.
"""

from __future__ import annotations

import dataclasses
import os
import re
import struct
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "Voxels",
    "RLEVolume",
    "SKIP_BITS",
    "DRAW_BITS",
    "MAX_SKIP",
    "MAX_DRAW",
    "MAX_VOXELS",
    "voxelize_mesh",
    "load_volume",
    "volume_to_voxels",
    "load_vxl",
    "load_kv6",
    "procedural_tree",
    "dense_to_voxels",
    "voxels_to_dense",
    "surface_mask",
    "surface_voxels",
    "downsample_voxels",
    "crop_voxels",
    "encode_rle",
    "decode_rle",
    "rle_stats",
    "place_instances",
    "save_scene",
    "load_scene",
    "as_jax",
]

SKIP_BITS = 10
DRAW_BITS = 6
MAX_SKIP = (1 << SKIP_BITS) - 1  # 1023
MAX_DRAW = (1 << DRAW_BITS) - 1  # 63
# Refuse grids whose dense occupancy would not fit comfortably in memory.
MAX_VOXELS = 1 << 31


class Voxels(NamedTuple):
    """A set of coloured voxels.

    Attributes:
        coords: (N, 3) int32 ``(x, y, z)`` voxel indices, y up, unique.
        colors: (N, 3) uint8 RGB.
        shape: ``(X, Y, Z)`` grid size; every coordinate lies inside it.
    """

    coords: np.ndarray
    colors: np.ndarray
    shape: tuple


def _check_resolution(resolution) -> int:
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        raise TypeError(f"resolution must be an int, got {type(resolution).__name__}")
    if resolution <= 0:
        raise ValueError(f"resolution must be > 0, got {resolution}")
    if int(resolution) ** 3 > MAX_VOXELS * 8:
        raise ValueError(f"resolution {resolution} is absurdly large (grid > 2^34 voxels)")
    return int(resolution)


def _check_shape(shape) -> tuple:
    shape = tuple(int(s) for s in shape)
    if len(shape) != 3 or min(shape) <= 0:
        raise ValueError(f"shape must be three positive ints, got {shape}")
    return shape


def _make_voxels(coords, colors, shape) -> Voxels:
    """Dedupes coordinates (first colour wins) and sorts by (x, z, -y)."""
    coords = np.asarray(coords, np.int64).reshape(-1, 3)
    colors = np.asarray(colors, np.uint8).reshape(-1, 3)
    X, Y, Z = shape
    key = (coords[:, 0] * Z + coords[:, 2]) * Y + (Y - 1 - coords[:, 1])
    key, idx = np.unique(key, return_index=True)
    return Voxels(coords[idx].astype(np.int32), colors[idx], shape)


# ---------------------------------------------------------------------------
# Dense grids and surfaces
# ---------------------------------------------------------------------------


def surface_mask(occupancy: np.ndarray) -> np.ndarray:
    """Solid voxels with at least one empty 6-neighbour (outside counts as empty).

    Only these can be hit by a ray from outside the solid (Fig. 4.10).

    Args:
        occupancy: (X, Y, Z) bool.

    Returns:
        (X, Y, Z) bool.
    """
    occ = np.asarray(occupancy, bool)
    if occ.ndim != 3:
        raise ValueError(f"occupancy must be 3-D, got shape {occ.shape}")
    p = np.pad(occ, 1, constant_values=False)
    inner = np.ones_like(occ)
    for axis in range(3):
        for shift in (-1, 1):
            inner &= np.roll(p, shift, axis=axis)[1:-1, 1:-1, 1:-1]
    return occ & ~inner


def dense_to_voxels(occupancy: np.ndarray, colors: np.ndarray, *, surface: bool = True) -> Voxels:
    """Dense grid -> :class:`Voxels`, keeping only surface voxels by default.

    Args:
        occupancy: (X, Y, Z) bool.
        colors: (X, Y, Z, 3) uint8 (or broadcastable).
        surface: drop voxels that have no empty 6-neighbour.
    """
    occ = np.asarray(occupancy, bool)
    mask = surface_mask(occ) if surface else occ
    idx = np.argwhere(mask)
    col = np.broadcast_to(np.asarray(colors, np.uint8), occ.shape + (3,))[mask]
    return _make_voxels(idx, col, occ.shape)


def voxels_to_dense(vox: Voxels) -> tuple[np.ndarray, np.ndarray]:
    """:class:`Voxels` -> dense ``(occupancy (X,Y,Z) bool, colors (X,Y,Z,3) uint8)``."""
    shape = _check_shape(vox.shape)
    if np.prod(shape, dtype=np.int64) > MAX_VOXELS:
        raise ValueError(f"grid {shape} too large for a dense copy; crop it first")
    occ = np.zeros(shape, bool)
    col = np.zeros(shape + (3,), np.uint8)
    c = np.asarray(vox.coords)
    occ[c[:, 0], c[:, 1], c[:, 2]] = True
    col[c[:, 0], c[:, 1], c[:, 2]] = vox.colors
    return occ, col


def _keys(coords, shape):
    X, Y, Z = shape
    c = np.asarray(coords, np.int64)
    return (c[:, 0] * Y + c[:, 1]) * Z + c[:, 2]


def surface_voxels(vox: Voxels) -> Voxels:
    """Keeps voxels with at least one empty 6-neighbour (sparse version of :func:`surface_mask`)."""
    shape = vox.shape
    keys = _keys(vox.coords, shape)
    order = np.argsort(keys)
    skeys = keys[order]
    c = np.asarray(vox.coords, np.int64)
    exposed = np.zeros(len(c), bool)
    for axis in range(3):
        for d in (-1, 1):
            n = c.copy()
            n[:, axis] += d
            outside = (n[:, axis] < 0) | (n[:, axis] >= shape[axis])
            nk = _keys(np.clip(n, 0, np.array(shape) - 1), shape)
            pos = np.clip(np.searchsorted(skeys, nk), 0, len(skeys) - 1)
            present = (skeys[pos] == nk) & ~outside
            exposed |= ~present
    return Voxels(vox.coords[exposed], vox.colors[exposed], shape)


def crop_voxels(vox: Voxels, lo, hi) -> Voxels:
    """Voxels inside the box ``[lo, hi)`` (3-vectors), shifted so that ``lo`` becomes 0."""
    lo = np.asarray(lo, np.int64)
    hi = np.asarray(hi, np.int64)
    if np.any(hi <= lo):
        raise ValueError(f"crop box must have hi > lo, got lo={lo}, hi={hi}")
    c = np.asarray(vox.coords, np.int64)
    m = np.all((c >= lo) & (c < hi), axis=1)
    return Voxels((c[m] - lo).astype(np.int32), vox.colors[m], tuple(int(v) for v in hi - lo))


def downsample_voxels(vox: Voxels) -> Voxels:
    """One mip level (4.4.7): a coarse voxel is set where any of its 2x2x2 children is.

    Its colour is the mean of the set children.
    """
    shape = tuple((s + 1) // 2 for s in vox.shape)
    c = np.asarray(vox.coords, np.int64) // 2
    k = _keys(c, shape)
    uk, inv, cnt = np.unique(k, return_inverse=True, return_counts=True)
    acc = np.zeros((len(uk), 3), np.float64)
    np.add.at(acc, inv, vox.colors.astype(np.float64))
    col = np.round(acc / cnt[:, None]).astype(np.uint8)
    X, Y, Z = shape
    coords = np.stack([uk // (Y * Z), (uk // Z) % Y, uk % Z], axis=1)
    return _make_voxels(coords, col, shape)


# ---------------------------------------------------------------------------
# 4.3.1 Mesh voxelization by edge interpolation
# ---------------------------------------------------------------------------


def _normal_colors(normals: np.ndarray) -> np.ndarray:
    n = normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    return np.clip(np.round(127.5 + 127.0 * n), 0, 255).astype(np.uint8)


def voxelize_mesh(
    vertices,
    faces,
    resolution: int,
    *,
    vertex_colors=None,
    samples_factor: float = 8.0,
    chunk_points: int = 1 << 22,
) -> Voxels:
    """Rasterizes triangles into voxels by interpolating along two edges (Eq. 4.1).

    The mesh is scaled uniformly so that its longest axis spans ``[0, resolution)``
    with its minimum corner at the origin (lowest voxel at y = 0).  Per triangle
    ``samples = samples_factor * max(|p2 - p1|, |p3 - p1|)`` (grid units) points
    are taken on the edges (p1, p2) and (p1, p3), and as many between each pair
    p12, p13 (Eq. 4.1 uses a factor of 8).

    Args:
        vertices: (V, 3) float positions, y up.
        faces: (F, 3) int triangle indices.
        resolution: grid size of the longest axis, > 0.
        vertex_colors: optional (V, 3) or (V, 4) uint8 colours, interpolated;
            without them a voxel's colour encodes its triangle's normal.
        samples_factor: the factor of Eq. 4.1.
        chunk_points: sample points processed at once (memory bound).

    Returns:
        The surface :class:`Voxels` of the shell.
    """
    resolution = _check_resolution(resolution)
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ValueError(f"vertices must have shape (V, 3) with V > 0, got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"faces must have shape (F, 3) with F > 0, got {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError("faces index outside vertices")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices must be finite")
    if not samples_factor > 0:
        raise ValueError(f"samples_factor must be > 0, got {samples_factor}")
    lo = v.min(axis=0)
    extent = v.max(axis=0) - lo
    if extent.max() <= 0:
        raise ValueError("mesh has zero extent")
    scale = resolution / extent.max()
    p = (v - lo) * scale
    shape = tuple(int(max(1, min(resolution, np.ceil(e * scale - 1e-9)))) for e in extent)
    if vertex_colors is not None:
        vc = np.asarray(vertex_colors)
        if vc.ndim != 2 or vc.shape[0] != len(v) or vc.shape[1] < 3:
            raise ValueError(f"vertex_colors must have shape (V, 3|4), got {vc.shape}")
        vc = vc[:, :3].astype(np.float64)
    else:
        fn = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
        face_col = _normal_colors(fn).astype(np.float64)
    p1, p2, p3 = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
    length = np.maximum(np.linalg.norm(p2 - p1, axis=1), np.linalg.norm(p3 - p1, axis=1))
    samples = np.maximum(1, np.ceil(samples_factor * length)).astype(np.int64)  # Eq. 4.1
    npts = (samples + 1) ** 2
    hi = np.array(shape) - 1
    all_keys, all_cols = [], []
    start = 0
    cum = np.cumsum(npts)
    while start < len(f):
        base = cum[start - 1] if start > 0 else 0
        stop = max(start + 1, int(np.searchsorted(cum, base + chunk_points, side="right")))
        tri = np.repeat(np.arange(start, stop), npts[start:stop])
        first = np.repeat(cum[start:stop] - npts[start:stop], npts[start:stop])
        local = np.arange(len(tri)) + base - first
        s = samples[tri]
        a = (local // (s + 1)) / s  # along both edges from p1
        b = (local % (s + 1)) / s  # between p12 and p13
        w2 = (a * (1.0 - b))[:, None]
        w3 = (a * b)[:, None]
        pts = p1[tri] + w2 * (p2[tri] - p1[tri]) + w3 * (p3[tri] - p1[tri])
        ijk = np.clip(np.floor(pts).astype(np.int64), 0, hi)
        key = _keys(ijk, shape)
        key, first_idx = np.unique(key, return_index=True)
        if vertex_colors is not None:
            ti = tri[first_idx]
            ww2, ww3 = w2[first_idx], w3[first_idx]
            col = (1 - ww2 - ww3) * vc[f[ti, 0]] + ww2 * vc[f[ti, 1]] + ww3 * vc[f[ti, 2]]
        else:
            col = face_col[tri[first_idx]]
        all_keys.append(key)
        all_cols.append(np.clip(np.round(col), 0, 255).astype(np.uint8))
        start = stop
    key = np.concatenate(all_keys)
    col = np.concatenate(all_cols)
    key, idx = np.unique(key, return_index=True)
    X, Y, Z = shape
    coords = np.stack([key // (Y * Z), (key // Z) % Y, key % Z], axis=1)
    return surface_voxels(_make_voxels(coords, col[idx], shape))


# ---------------------------------------------------------------------------
# 4.3.2 Volume import
# ---------------------------------------------------------------------------

_MET_TYPES = {
    "MET_UCHAR": "u1",
    "MET_CHAR": "i1",
    "MET_USHORT": "u2",
    "MET_SHORT": "i2",
    "MET_UINT": "u4",
    "MET_INT": "i4",
    "MET_FLOAT": "f4",
    "MET_DOUBLE": "f8",
}
_NRRD_TYPES = {
    "uchar": "u1",
    "unsigned char": "u1",
    "uint8": "u1",
    "char": "i1",
    "signed char": "i1",
    "int8": "i1",
    "short": "i2",
    "int16": "i2",
    "signed short": "i2",
    "ushort": "u2",
    "unsigned short": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "double": "f8",
}


def _read_header(path: str) -> dict:
    out = {}
    with open(path, encoding="latin-1") as fh:
        for line in fh:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            m = re.match(r"([^:=]+?)\s*(:=|=|:)\s*(.*)$", line)
            if m:
                out[m.group(1).strip().lower()] = m.group(3).strip()
    return out


def _read_raw(files, dims, dtype, what):
    want = int(np.prod(dims)) * np.dtype(dtype).itemsize
    chunks = []
    for name in files:
        if not os.path.exists(name):
            raise ValueError(f"{what}: data file {name!r} not found")
        with open(name, "rb") as fh:
            chunks.append(fh.read())
    data = b"".join(chunks)
    if len(data) != want:
        raise ValueError(
            f"{what}: data has {len(data)} bytes, header dims {tuple(dims)} of {dtype} need {want}"
        )
    # x varies fastest in both formats.
    return np.frombuffer(data, dtype).reshape(tuple(dims[::-1])).transpose(2, 1, 0)


def load_volume(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Reads a scanned volume from a MetaImage (``.mhd``) or NRRD (``.nhdr``/``.nrrd``) header.

    Args:
        path: header file; raw data files are resolved beside it.

    Returns:
        ``(volume (X, Y, Z) in the file's dtype, spacing (3,) float)``.

    Raises:
        ValueError: unknown header, missing data or a data size that does not match.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ValueError(f"path: volume header {path!r} not found")
    d = os.path.dirname(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".mhd":
        h = _read_header(path)
        try:
            dims = [int(x) for x in h["dimsize"].split()]
            dtype = np.dtype(_MET_TYPES[h["elementtype"]])
            datafile = h["elementdatafile"]
        except KeyError as e:
            raise ValueError(f"path: MetaImage header {path!r} lacks or misuses {e}") from None
        msb = h.get("elementbyteordermsb", h.get("binarydatabyteordermsb", "False"))
        dtype = dtype.newbyteorder(">" if msb.lower() == "true" else "<")
        spacing = [float(x) for x in h.get("elementspacing", "1 1 1").split()]
        files = [os.path.join(d, datafile)]
    elif ext in (".nhdr", ".nrrd"):
        with open(path, "rb") as fh:
            magic = fh.read(4)
        if magic != b"NRRD":
            raise ValueError(f"path: {path!r} is not a NRRD header")
        h = _read_header(path)
        try:
            dims = [int(x) for x in h["sizes"].split()]
            dtype = np.dtype(_NRRD_TYPES[h["type"]])
        except KeyError as e:
            raise ValueError(f"path: NRRD header {path!r} lacks or misuses {e}") from None
        if h.get("encoding", "raw") != "raw":
            raise ValueError(f"path: only raw NRRD encoding is supported, got {h['encoding']}")
        dtype = dtype.newbyteorder(">" if h.get("endian", "little") == "big" else "<")
        spacing = [float(x) for x in h.get("spacings", "1 1 1").split()]
        spec = h.get("data file", h.get("datafile"))
        if spec is None:
            raise ValueError("path: attached NRRD data is not supported; use a detached header")
        parts = spec.split()
        if "%" in parts[0] and len(parts) >= 4:
            lo, hi, step = int(parts[1]), int(parts[2]), int(parts[3])
            files = [os.path.join(d, parts[0] % i) for i in range(lo, hi + 1, step)]
        else:
            files = [os.path.join(d, parts[0])]
    else:
        raise ValueError(f"path: unknown volume header extension {ext!r} (want .mhd or .nhdr)")
    if len(dims) != 3:
        raise ValueError(f"path: volume must be 3-D, header gives dims {dims}")
    vol = _read_raw(files, dims, dtype, "path")
    return vol.astype(dtype.newbyteorder("=")), np.asarray(spacing[:3], np.float64)


def volume_to_voxels(volume, iso: float, *, up_axis: int = 1) -> Voxels:
    """Thresholds a scanned volume at an iso value and keeps its surface (4.3.2).

    Voxels with ``value >= iso`` are solid.  The colour is a gradient over the
    value above the iso level (dark brown to light green, as the thesis does to
    emphasize leaves in the bonsai).

    Args:
        volume: (X, Y, Z) scalar volume.
        iso: threshold, strictly inside the data range.
        up_axis: which volume axis becomes world y.
    """
    vol = np.asarray(volume)
    if vol.ndim != 3:
        raise ValueError(f"volume must be 3-D, got shape {vol.shape}")
    if up_axis not in (0, 1, 2):
        raise ValueError(f"up_axis must be 0, 1 or 2, got {up_axis}")
    lo, hi = float(vol.min()), float(vol.max())
    if not (np.isfinite(iso) and lo < iso <= hi):
        raise ValueError(f"iso {iso} outside the data range ({lo}, {hi}]")
    order = {0: (1, 0, 2), 1: (0, 1, 2), 2: (0, 2, 1)}[up_axis]
    vol = np.transpose(vol, order)
    occ = vol >= iso
    t = np.clip((vol.astype(np.float64) - iso) / max(hi - iso, 1e-12), 0, 1)[..., None]
    c0 = np.array([90, 60, 30], np.float64)
    c1 = np.array([170, 230, 120], np.float64)
    col = np.round(c0 + t * (c1 - c0)).astype(np.uint8)
    return dense_to_voxels(occ, col)


# ---------------------------------------------------------------------------
# Voxlap formats
# ---------------------------------------------------------------------------


def _bgra_to_rgb(words: np.ndarray) -> np.ndarray:
    b = words.view(np.uint8).reshape(-1, 4)
    return b[:, [2, 1, 0]].copy()


def load_vxl(path: str) -> Voxels:
    """Reads a Voxlap ``.vxl`` world as its coloured surface voxels.

    World mapping: Voxlap (x, y, z-down) -> ours (x, 255 - z, y) for a 256-high map.
    Spans are located with pointer doubling over all words of the file, so the
    parse is vectorized (no Python loop per span).

    Raises:
        ValueError: wrong magic, or a truncated / inconsistent file.
    """
    with open(path, "rb") as fh:
        data = fh.read()
    if len(data) < 12 + 96 + 4:
        raise ValueError(f"path: {path!r} is too short for a .vxl file")
    magic, sx, sy = struct.unpack_from("<III", data, 0)
    if magic != 0x09072000:
        raise ValueError(f"path: {path!r} has bad .vxl magic {magic:#x}")
    if not (0 < sx <= 16384 and 0 < sy <= 16384):
        raise ValueError(f"path: {path!r} has bad .vxl size {sx}x{sy}")
    body = np.frombuffer(data, np.uint8, offset=108)
    if len(body) % 4:
        raise ValueError(f"path: {path!r} is truncated (body not whole words)")
    w = body.reshape(-1, 4).astype(np.int64)
    nw = len(w)
    N, S, E = w[:, 0], w[:, 1], w[:, 2]
    step = np.where(N > 0, N, E - S + 2)
    nxt = np.arange(nw) + np.maximum(step, 1)
    nxt = np.minimum(nxt, nw)  # nw is the absorbing end sentinel
    jump = np.append(nxt, nw)
    pos = np.array([0], np.int64)
    # Pointer doubling: pos holds the first m span headers, jump = next^m.
    while pos[-1] < nw:
        more = jump[pos]
        pos = np.concatenate([pos, more])
        jump = jump[jump]
    pos = pos[pos < nw]
    last_end = pos[-1] + (E[pos[-1]] - S[pos[-1]] + 2) if N[pos[-1]] == 0 else -1
    if N[pos[-1]] != 0 or last_end != nw:
        raise ValueError(f"path: {path!r} is truncated or corrupt (spans do not end the file)")
    n, s, e = N[pos], S[pos], E[pos]
    if np.any(e < s - 1):
        raise ValueError(f"path: {path!r} is corrupt (span with E < S - 1)")
    col = np.concatenate([[0], np.cumsum(n == 0)[:-1]])
    if col[-1] + 1 != sx * sy:
        raise ValueError(f"path: {path!r} holds {col[-1] + 1} columns, header says {sx * sy}")
    words = np.frombuffer(data, np.uint32, offset=108)
    # Top runs: z = S..E, colours right after the header.
    ntop = e - s + 1
    span_t = np.repeat(np.arange(len(pos)), ntop)
    off_t = np.arange(ntop.sum()) - np.repeat(np.cumsum(ntop) - ntop, ntop)
    z_top = s[span_t] + off_t
    c_top = words[pos[span_t] + 1 + off_t]
    # Bottom runs: (N-1)-(E-S+1) colours ending just above the next span's A.
    nbot = np.where(n > 0, n - 1 - ntop, 0)
    if np.any(nbot < 0):
        raise ValueError(f"path: {path!r} is corrupt (span shorter than its top run)")
    a_next = np.append(w[pos[1:], 3], 0)
    span_b = np.repeat(np.arange(len(pos)), nbot)
    off_b = np.arange(nbot.sum()) - np.repeat(np.cumsum(nbot) - nbot, nbot)
    z_bot = a_next[span_b] - nbot[span_b] + off_b
    c_bot = words[pos[span_b] + 1 + ntop[span_b] + off_b]
    span = np.concatenate([span_t, span_b])
    z = np.concatenate([z_top, z_bot])
    c = np.concatenate([c_top, c_bot])
    cx = col[span] % sx
    cy = col[span] // sx
    height = 256
    if z.max(initial=0) >= height or z.min(initial=0) < 0:
        raise ValueError(f"path: {path!r} has z outside [0, {height})")
    coords = np.stack([cx, height - 1 - z, cy], axis=1)
    return _make_voxels(coords, _bgra_to_rgb(c.astype(np.uint32)), (sx, height, sy))


def load_kv6(path: str) -> Voxels:
    """Reads a Voxlap ``.kv6`` sprite (surface voxels only, as stored).

    World mapping: Voxlap (x, y, z-down) -> ours (x, zsiz - 1 - z, y).

    Raises:
        ValueError: wrong magic, truncated file or inconsistent column counts.
    """
    with open(path, "rb") as fh:
        data = fh.read()
    if len(data) < 32 or data[:4] != b"Kvxl":
        raise ValueError(f"path: {path!r} is not a .kv6 file (bad magic or too short)")
    xs, ys, zs = struct.unpack_from("<iii", data, 4)
    (num,) = struct.unpack_from("<i", data, 28)
    if min(xs, ys, zs) <= 0 or num < 0:
        raise ValueError(f"path: {path!r} has bad sizes {xs}x{ys}x{zs}, {num} voxels")
    need = 32 + 8 * num + 4 * xs + 2 * xs * ys
    if len(data) < need:
        raise ValueError(f"path: {path!r} is truncated ({len(data)} bytes, need {need})")
    rec = np.frombuffer(data, np.uint8, count=8 * num, offset=32).reshape(num, 8)
    color = rec[:, :4].copy().view(np.uint32).ravel()
    z = rec[:, 4].astype(np.int64) | (rec[:, 5].astype(np.int64) << 8)
    xlen = np.frombuffer(data, "<u4", count=xs, offset=32 + 8 * num).astype(np.int64)
    ylen = np.frombuffer(data, "<u2", count=xs * ys, offset=32 + 8 * num + 4 * xs)
    ylen = ylen.astype(np.int64)
    if xlen.sum() != num or ylen.sum() != num:
        raise ValueError(f"path: {path!r} column counts do not add up to {num} voxels")
    colid = np.repeat(np.arange(xs * ys), ylen)
    if np.any(z >= zs):
        raise ValueError(f"path: {path!r} has z outside [0, {zs})")
    coords = np.stack([colid // ys, zs - 1 - z, colid % ys], axis=1)
    return _make_voxels(coords, _bgra_to_rgb(color), (xs, zs, ys))


# ---------------------------------------------------------------------------
# 4.3.3 Procedural trees
# ---------------------------------------------------------------------------


def procedural_tree(resolution: int = 64, *, key, depth: int = 4) -> Voxels:
    """A voxel tree: spheres along branches, midpoint displacement, 2-3-way splits (4.3.3).

    Args:
        resolution: grid size (the tree fits a ``resolution``-cube).
        key: ``jax.random`` key; the same key gives the same tree.
        depth: branching generations.

    Returns:
        Surface :class:`Voxels` (trunk brown, leaf clusters green).
    """
    resolution = _check_resolution(resolution)
    if resolution < 8:
        raise ValueError(f"resolution must be >= 8 for a tree, got {resolution}")
    if not 1 <= depth <= 7:
        raise ValueError(f"depth must be in [1, 7], got {depth}")
    rnd = iter(np.asarray(jax.random.uniform(key, (1 << 16,)), np.float64))
    R = float(resolution)
    spheres = []  # (center, radius, is_leaf)

    def branch_points(a, b, disp, level):
        # Random midpoint displacement: recursively insert displaced midpoints.
        if level == 0:
            return [a, b]
        m = 0.5 * (a + b) + disp * (np.array([next(rnd), next(rnd), next(rnd)]) - 0.5)
        return branch_points(a, m, disp * 0.5, level - 1)[:-1] + branch_points(
            m, b, disp * 0.5, level - 1
        )

    def grow(p0, direction, length, radius, gen):
        p1 = p0 + direction * length
        pts = branch_points(p0, p1, 0.35 * length, 3)
        for i in range(len(pts) - 1):
            a, b = pts[i], pts[i + 1]
            n = max(2, int(np.ceil(np.linalg.norm(b - a) / max(0.5 * radius, 0.5))))
            for t in np.linspace(0.0, 1.0, n, endpoint=False):
                spheres.append((a + t * (b - a), radius, False))
        if gen >= depth:
            spheres.append((p1, max(2.0, 2.5 * radius + 0.04 * R), True))
            return
        k = 2 + int(next(rnd) < 0.5)
        for j in range(k):
            ang = 2 * np.pi * (j + next(rnd) * 0.5) / k
            tilt = 0.5 + 0.4 * next(rnd)
            d = np.array([np.cos(ang) * tilt, 1.0, np.sin(ang) * tilt])
            d = 0.6 * direction + 0.4 * d / np.linalg.norm(d)
            d /= np.linalg.norm(d)
            grow(p1, d, length * (0.6 + 0.15 * next(rnd)), radius * 0.65, gen + 1)

    root = np.array([R / 2, 0.0, R / 2])
    grow(root, np.array([0.0, 1.0, 0.0]), 0.3 * R, 0.05 * R, 1)
    occ = np.zeros((resolution,) * 3, bool)
    col = np.zeros((resolution,) * 3 + (3,), np.uint8)
    g = np.arange(resolution) + 0.5
    for center, radius, leaf in spheres:
        lo = np.maximum(np.floor(center - radius).astype(int), 0)
        hi = np.minimum(np.ceil(center + radius).astype(int) + 1, resolution)
        if np.any(hi <= lo):
            continue
        xx, yy, zz = np.meshgrid(
            g[lo[0] : hi[0]], g[lo[1] : hi[1]], g[lo[2] : hi[2]], indexing="ij"
        )
        inside = (xx - center[0]) ** 2 + (yy - center[1]) ** 2 + (zz - center[2]) ** 2 <= radius**2
        sub = occ[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        csub = col[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        new = inside & ~sub
        shade = np.clip(yy / R, 0, 1)[..., None]
        if leaf:
            c = np.array([40, 120, 30]) + shade * np.array([60, 90, 30])
        else:
            c = np.array([80, 50, 25]) + shade * np.array([40, 30, 15])
        csub[new] = np.round(np.broadcast_to(c, new.shape + (3,))[new]).astype(np.uint8)
        sub |= inside
    return dense_to_voxels(occ, col)


# ---------------------------------------------------------------------------
# 4.4.6 RLE encoding
# ---------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RLEVolume:
    """Run-length encoded surface voxels with a pointer map and mip levels (Fig. 4.11).

    Column ``c = x * Z_l + z`` of level ``l`` is entry ``level_offsets[l] + c``
    of the pointer-map arrays.  An element is ``skip << 6 | draw`` (10 + 6 bits):
    ``skip`` empty voxels, then ``draw`` coloured ones, counted from the top of
    the column (y = Y_l - 1) downwards.

    Attributes:
        first: (C,) uint16, the column's first element, inline in the pointer map.
        count: (C,) uint16, elements in the column (0 = empty column).
        ptr: (C,) uint32, index in ``elements`` of the column's second element.
        color_ptr: (C,) uint32, index in ``colors`` of the column's first drawn voxel.
        elements: (M,) uint16, every column's elements after the first.
        colors: (K, 3) uint8, one RGB per drawn voxel in column order, top to bottom.
        tiles: (TX, TZ) int32 instance map: the scene is a TX x TZ grid of
            object-sized tiles, each holding the object (0) or nothing (-1).
            A plain volume is one tile.  Instances share every column.
        empty_dist: (C,) uint8 empty-space distance map (not in the thesis,
            see :func:`empty_space_distance`): per column, the chessboard
            distance in its level's cells to the nearest non-empty column of
            the same level (0 = non-empty), capped at 255; periodic in an
            instance map.  The ray caster jumps over the empty square it bounds.
        shape: static ``(X, Y, Z)`` of the whole scene at level 0
            (``TX * X_0, Y_0, TZ * Z_0``).
        level_shapes: static tuple of the object's ``(X_l, Y_l, Z_l)``.
        level_offsets: static tuple, first pointer-map entry of each level.
        max_elements: static, the largest column element count over all levels.
        voxel_counts: static tuple, drawn voxels per level.
    """

    first: jax.Array
    count: jax.Array
    ptr: jax.Array
    color_ptr: jax.Array
    elements: jax.Array
    colors: jax.Array
    tiles: jax.Array
    empty_dist: jax.Array
    shape: tuple = dataclasses.field(metadata=dict(static=True))
    level_shapes: tuple = dataclasses.field(metadata=dict(static=True))
    level_offsets: tuple = dataclasses.field(metadata=dict(static=True))
    max_elements: int = dataclasses.field(metadata=dict(static=True))
    voxel_counts: tuple = dataclasses.field(metadata=dict(static=True))

    @property
    def levels(self) -> int:
        return len(self.level_shapes)


def empty_space_distance(occupied: np.ndarray, *, periodic: bool = False, cap: int = 255):
    """Chessboard distance from each map cell to the nearest occupied cell.

    Every cell ``(x', z')`` with ``max(|x' - x|, |z' - z|) < d[x, z]`` is
    empty, so a ray in cell ``(x, z)`` may jump to the exit of that square.

    Args:
        occupied: (X, Z) bool, columns holding at least one element.
        periodic: False: cells outside the grid are empty (one object, the
            map ends there).  True: the grid repeats (an instance map whose
            every tile holds this object or nothing, see :func:`place_instances`).
        cap: largest distance stored (also the result where nothing is occupied).

    Returns:
        (X, Z) uint8 distances, 0 on occupied cells.
    """
    occ = np.asarray(occupied, bool)
    d = np.full(occ.shape, cap, np.uint8)
    if not occ.any():
        return d

    def grow(a, axis):
        if periodic:
            return a | np.roll(a, 1, axis) | np.roll(a, -1, axis)
        g = a.copy()
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(1, None), slice(None, -1)
        g[tuple(lo)] |= a[tuple(hi)]
        g[tuple(hi)] |= a[tuple(lo)]
        return g

    reach = occ.copy()
    # Each pass grows the reached set by one ring (a separable 3x3 dilation).
    for r in range(cap):
        d[reach & (d == cap)] = r
        if reach.all():
            break
        reach = grow(grow(reach, 0), 1)
    return d


def _empty_distances(count, level_shapes, level_offsets, periodic):
    """The :attr:`RLEVolume.empty_dist` map of every level, (C,) uint8."""
    out = []
    for (X, _, Z), o in zip(level_shapes, level_offsets):
        occ = np.asarray(count[o : o + X * Z]).reshape(X, Z) > 0
        out.append(empty_space_distance(occ, periodic=periodic).reshape(-1))
    return np.concatenate(out).astype(np.uint8)


def _encode_level(vox: Voxels):
    """Encodes one level: returns (first, count, ptr_local, color_ptr, elements, colors)."""
    X, Y, Z = vox.shape
    c = np.asarray(vox.coords, np.int64)
    colors = np.asarray(vox.colors, np.uint8)
    ncols = X * Z
    colid = c[:, 0] * Z + c[:, 2]
    order = np.lexsort((-c[:, 1], colid))  # column, then top to bottom
    colid, y, colors = colid[order], c[order, 1], colors[order]
    n = len(y)
    if n:
        new_run = np.ones(n, bool)
        new_run[1:] = (colid[1:] != colid[:-1]) | (y[1:] != y[:-1] - 1)
        run_start = np.flatnonzero(new_run)
        run_len = np.diff(np.append(run_start, n))
        run_col = colid[run_start]
        run_top = y[run_start]
        first_in_col = np.ones(len(run_start), bool)
        first_in_col[1:] = run_col[1:] != run_col[:-1]
        prev_bottom = np.empty(len(run_start), np.int64)
        prev_bottom[0] = Y
        prev_bottom[1:] = run_top[:-1] - run_len[:-1] + 1
        prev_bottom[first_in_col] = Y
        skip = prev_bottom - 1 - run_top
    else:
        run_len = run_col = skip = np.zeros(0, np.int64)
    # Long skips become (1023, 0) elements; long runs continue as (0, <=63).
    n_skip_el = np.maximum(0, (skip - 1) // MAX_SKIP)
    n_draw_el = np.maximum(1, -(-run_len // MAX_DRAW))
    per_run = n_skip_el + n_draw_el
    run_of = np.repeat(np.arange(len(run_len)), per_run)
    k = np.arange(per_run.sum()) - np.repeat(np.cumsum(per_run) - per_run, per_run)
    ns = n_skip_el[run_of]
    is_skip = k < ns
    kd = k - ns
    el_skip = np.where(is_skip, MAX_SKIP, np.where(kd == 0, skip[run_of] - ns * MAX_SKIP, 0))
    el_draw = np.where(is_skip, 0, np.minimum(MAX_DRAW, run_len[run_of] - kd * MAX_DRAW))
    el = ((el_skip << DRAW_BITS) | el_draw).astype(np.uint16)
    el_col = run_col[run_of]
    count = np.bincount(el_col, minlength=ncols).astype(np.int64)
    if count.max(initial=0) > 0xFFFF:
        raise ValueError("a column needs more than 65535 RLE elements")
    start = np.cumsum(count) - count
    first = np.zeros(ncols, np.uint16)
    nonempty = count > 0
    first[nonempty] = el[start[nonempty]]
    is_first = np.zeros(len(el), bool)
    is_first[start[nonempty]] = True
    rest = el[~is_first]
    ptr = (np.cumsum(np.maximum(count - 1, 0)) - np.maximum(count - 1, 0)).astype(np.int64)
    drawn = np.bincount(colid, minlength=ncols).astype(np.int64)
    color_ptr = np.cumsum(drawn) - drawn
    return first, count, ptr, color_ptr, rest, colors


def encode_rle(vox: Voxels, *, levels: int = 1) -> RLEVolume:
    """Encodes surface voxels into the pointer map + RLE columns, with mip levels.

    Args:
        vox: coloured voxels (normally only the surface, see :func:`surface_voxels`).
        levels: number of levels; level ``l`` is ``l`` times 2x down-sampled.

    Returns:
        The :class:`RLEVolume` (NumPy-backed leaves; ``jax.device_put`` it for speed).
    """
    shape = _check_shape(vox.shape)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 1:
        raise ValueError(f"levels must be an int >= 1, got {levels}")
    c = np.asarray(vox.coords)
    if len(c) and (c.min() < 0 or np.any(c.max(axis=0) >= np.array(shape))):
        raise ValueError(f"voxel coordinates outside the grid {shape}")
    parts = []
    cur = vox
    for _ in range(levels):
        parts.append((cur.shape, len(cur.coords), _encode_level(cur)))
        cur = downsample_voxels(cur)
    firsts, counts, ptrs, cptrs, els, cols = [], [], [], [], [], []
    offsets, shapes, nvox = [], [], []
    col_base = el_base = c_base = 0
    for shp, nv, (first, count, ptr, cptr, el, col) in parts:
        offsets.append(col_base)
        shapes.append(tuple(int(s) for s in shp))
        nvox.append(int(nv))
        firsts.append(first)
        counts.append(count)
        ptrs.append(ptr + el_base)
        cptrs.append(cptr + c_base)
        els.append(el)
        cols.append(col)
        col_base += len(first)
        el_base += len(el)
        c_base += len(col)
    count = np.concatenate(counts)
    return RLEVolume(
        first=np.concatenate(firsts).astype(np.uint16),
        count=count.astype(np.uint16),
        ptr=np.concatenate(ptrs).astype(np.uint32),
        color_ptr=np.concatenate(cptrs).astype(np.uint32),
        elements=np.concatenate(els).astype(np.uint16) if el_base else np.zeros(1, np.uint16),
        colors=np.concatenate(cols).astype(np.uint8) if c_base else np.zeros((1, 3), np.uint8),
        tiles=np.zeros((1, 1), np.int32),
        empty_dist=_empty_distances(count, shapes, offsets, periodic=False),
        shape=shape,
        level_shapes=tuple(shapes),
        level_offsets=tuple(offsets),
        max_elements=int(max(1, count.max(initial=0))),
        voxel_counts=tuple(nvox),
    )


def decode_rle(rle: RLEVolume, level: int = 0) -> Voxels:
    """Decodes one level back into :class:`Voxels` (exact inverse of :func:`encode_rle`)."""
    if not 0 <= level < rle.levels:
        raise ValueError(f"level must be in [0, {rle.levels}), got {level}")
    X, Y, Z = rle.level_shapes[level]
    o = rle.level_offsets[level]
    ncols = X * Z
    count = np.asarray(rle.count[o : o + ncols], np.int64)
    first = np.asarray(rle.first[o : o + ncols])
    ptr = np.asarray(rle.ptr[o : o + ncols], np.int64)
    cptr = np.asarray(rle.color_ptr[o : o + ncols], np.int64)
    elements = np.asarray(rle.elements)
    colors = np.asarray(rle.colors)
    col = np.repeat(np.arange(ncols), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    el = np.where(k == 0, first[col], elements[np.maximum(ptr[col] + k - 1, 0)])
    el = el.astype(np.int64)
    skip, draw = el >> DRAW_BITS, el & MAX_DRAW
    # Height of each element's first drawn voxel: column top minus everything above.
    adv = skip + draw
    col_start = np.repeat(np.cumsum(count) - count, count)
    before = np.cumsum(adv) - adv
    above = before - np.concatenate([[0], np.cumsum(adv)])[col_start]
    top = Y - 1 - above - skip
    vid = np.repeat(np.arange(len(el)), draw)
    j = np.arange(draw.sum()) - np.repeat(np.cumsum(draw) - draw, draw)
    y = top[vid] - j
    drawn_before = np.cumsum(draw) - draw
    cstart = np.concatenate([[0], np.cumsum(draw)])[col_start]
    cidx = cptr[col[vid]] + (drawn_before[vid] - cstart[vid]) + j
    c = col[vid]
    coords = np.stack([c // Z, y, c % Z], axis=1).astype(np.int32)
    rgb = colors[cidx] if len(cidx) else np.zeros((0, 3), np.uint8)
    tiles = np.asarray(rle.tiles)
    if tiles.shape == (1, 1) and tiles[0, 0] == 0:
        return Voxels(coords, rgb, (X, Y, Z))
    where = np.argwhere(tiles >= 0)
    coords = np.concatenate([coords + [tx * X, 0, tz * Z] for tx, tz in where])
    rgb = np.concatenate([rgb] * len(where))
    shape = (tiles.shape[0] * X, Y, tiles.shape[1] * Z)
    return _make_voxels(coords, rgb, shape)


def rle_stats(rle: RLEVolume) -> dict:
    """Memory accounting as in Table 4.1 (bits/voxel) and Table 4.2 (bytes with colour).

    Position data = 64 bits per pointer-map entry (32-bit pointer, 16-bit count,
    16-bit first element) plus 16 bits per further element, summed over all mip
    levels, divided by the level-0 voxel count.  Colour data = 24-bit RGB per
    stored drawn voxel (all levels) plus our 32-bit colour pointer per column.
    Buffers are counted as stored, so instances sharing columns count once.
    ``empty_dist_bytes`` is our empty-space distance map (one byte per
    pointer-map entry, not in the thesis), reported apart from both.
    """
    entries = int(np.asarray(rle.count).shape[0])
    count = np.asarray(rle.count, np.int64)
    total_elements = int(count.sum())
    # Buffers as stored: instanced scenes share one element / colour buffer.
    stored = int(np.asarray(rle.elements).shape[0]) if int(np.maximum(count - 1, 0).sum()) else 0
    ntiles = int(np.asarray(rle.tiles).size)
    # 64 bits per pointer-map entry, 16 per stored element, 32 per instance tile.
    position_bits = 64 * entries + 16 * stored + (32 * ntiles if ntiles > 1 else 0)
    nvox0 = max(1, rle.voxel_counts[0])
    ncolors = int(np.asarray(rle.colors).shape[0]) if sum(rle.voxel_counts) else 0
    color_bytes = 3 * ncolors + 4 * entries
    return dict(
        voxels=int(rle.voxel_counts[0]),
        voxels_all_levels=int(sum(rle.voxel_counts)),
        rle_elements=total_elements,
        rle_elements_level0=int(count[: rle.level_offsets[1]].sum())
        if rle.levels > 1
        else total_elements,
        pointer_map_entries=entries,
        position_bytes=position_bits // 8,
        bits_per_voxel=position_bits / nvox0,
        bytes_with_color=position_bits // 8 + color_bytes,
        bytes_per_voxel_with_color=(position_bits / 8 + color_bytes) / nvox0,
        empty_dist_bytes=int(np.asarray(rle.empty_dist).shape[0]),
    )


def place_instances(rle: RLEVolume, tiles, grid) -> RLEVolume:
    """A large map of many copies of one object that share all of its columns.

    The scene is a grid of object-sized tiles; a tile map of 32-bit entries
    says where the object stands.  No column, element or colour is copied, so
    memory grows only by the tile map (the thesis's 3000-tree forest and 1600
    Imrods).

    Args:
        rle: the object (one tile); its x and z sizes must be multiples of
            ``2 ** (levels - 1)`` so that every mip level tiles exactly.
        tiles: (K, 2) integer ``(tx, tz)`` tile positions of the copies.
        grid: ``(TX, TZ)`` tiles of the map.

    Raises:
        ValueError: a copy outside the grid, two copies on one tile, or an
            object size that does not tile its mip levels.
    """
    t = np.asarray(tiles, np.int64).reshape(-1, 2)
    TX, TZ = (int(v) for v in grid)
    X, Y, Z = rle.level_shapes[0]
    if np.asarray(rle.tiles).shape != (1, 1):
        raise ValueError("rle: already an instanced scene")
    if TX <= 0 or TZ <= 0:
        raise ValueError(f"grid must be positive, got {grid}")
    align = 1 << (rle.levels - 1)
    if X % align or Z % align:
        raise ValueError(f"object x/z size {X}x{Z} must be multiples of {align} for its mips")
    if len(t) == 0:
        raise ValueError("tiles: need at least one instance")
    if np.any(t < 0) or np.any(t[:, 0] >= TX) or np.any(t[:, 1] >= TZ):
        raise ValueError(f"tiles: an instance leaves the {TX}x{TZ} grid")
    m = np.full((TX, TZ), -1, np.int32)
    for i, (a, b) in enumerate(t):
        if m[a, b] >= 0:
            raise ValueError(f"tiles: instance {i} overlaps another at tile ({a}, {b})")
        m[a, b] = 0
    return dataclasses.replace(
        rle,
        tiles=m,
        # Neighbouring tiles hold the object or nothing: a periodic distance
        # map is safe across tile borders.
        empty_dist=_empty_distances(rle.count, rle.level_shapes, rle.level_offsets, True),
        shape=(TX * X, Y, TZ * Z),
        voxel_counts=tuple(int(n) * len(t) for n in rle.voxel_counts),
    )


def save_scene(path: str, vox: Voxels) -> None:
    """Writes voxels to an ``.npz`` atomically (temp file in the same folder, then replace)."""
    from jaxgfx.io import atomic_write

    with atomic_write(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(
                fh, coords=vox.coords, colors=vox.colors, shape=np.asarray(vox.shape, np.int64)
            )


def load_scene(path: str) -> Voxels:
    """Reads voxels written by :func:`save_scene`."""
    if not os.path.exists(path):
        raise ValueError(f"scene: {path!r} not found")
    with np.load(path) as z:
        try:
            return Voxels(
                z["coords"].astype(np.int32),
                z["colors"].astype(np.uint8),
                tuple(int(s) for s in z["shape"]),
            )
        except KeyError as e:
            raise ValueError(f"scene: {path!r} lacks array {e}") from None


def as_jax(rle: RLEVolume) -> RLEVolume:
    """Moves an :class:`RLEVolume`'s buffers to the default JAX device."""
    return jax.tree_util.tree_map(jnp.asarray, rle)
