"""Reading and writing voxel data: scanned volumes (thesis 4.3.2), Voxlap files, scenes.

Scanned volumes come as raw data beside a MetaImage (``.mhd``) or NRRD (``.nhdr``)
header, as VTK legacy structured points (``.vtk``), or, with the optional SimpleITK
(``jaxgfx[volumes]``), as NIfTI, ``.mha`` and compressed NRRD (:mod:`.volume`).  They
are resampled to cubic voxels by their sample spacing and thresholded at an iso
value (:func:`volume_to_voxels`).  Voxlap's
``.vxl`` worlds and ``.kv6`` sprites are run-length encoded surface voxels of the
same family as the thesis's.  :func:`save_scene` / :func:`load_scene` keep a
:class:`~jaxgfx.raycast.Voxels` in an ``.npz``.
"""

from __future__ import annotations

import os
import re
import struct

import numpy as np

from jaxgfx._src.voxel.volume import (
    load_vtk_structured_points,
    load_with_simpleitk,
    otsu_threshold,
    resample_isotropic,
    turn_up,
)
from jaxgfx._src.voxel.voxset import Voxels, as_voxels, dense_to_voxels, make_voxels

__all__ = [
    "VOLUME_SUFFIXES",
    "SIMPLEITK_SUFFIXES",
    "volume_suffix",
    "load_volume",
    "volume_to_voxels",
    "load_vxl",
    "load_kv6",
    "save_scene",
    "load_scene",
]


# ---------------------------------------------------------------------------
# 4.3.2 Volume import
# ---------------------------------------------------------------------------

VOLUME_SUFFIXES = (".mhd", ".nhdr", ".nrrd", ".vtk")
"""Volume files read without extra packages (raw MetaImage / NRRD data, VTK legacy)."""
SIMPLEITK_SUFFIXES = (".mha", ".nii", ".nii.gz", ".hdr", ".img", ".gipl", ".gipl.gz")
"""Volume files read through SimpleITK, the optional extra ``jaxgfx[volumes]``."""

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


def _nrrd_spacing(h: dict, path: str) -> list[float]:
    """NRRD ``spacings``, else the lengths of the ``space directions`` vectors, else 1."""
    if "spacings" in h:
        return [float(x) for x in h["spacings"].split()]
    if "space directions" in h:
        vectors = re.findall(r"\(([^)]*)\)", h["space directions"])
        if len(vectors) != 3:
            raise ValueError(f"path: NRRD header {path!r} has space directions {vectors}, want 3")
        return [float(np.linalg.norm([float(x) for x in v.split(",")])) for v in vectors]
    return [1.0, 1.0, 1.0]


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


def volume_suffix(path) -> str:
    """The volume file suffix of ``path`` (lower case, ``.nii.gz`` whole), or ``''``."""
    name = os.fspath(path).lower()
    for suffix in VOLUME_SUFFIXES + SIMPLEITK_SUFFIXES:
        if name.endswith(suffix):
            return suffix
    return ""


def load_volume(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Reads a scanned volume and its sample spacing.

    Built in: MetaImage (``.mhd``) and NRRD (``.nhdr``/``.nrrd``) headers with raw
    data, and VTK legacy ``STRUCTURED_POINTS`` (``.vtk``).  Through SimpleITK (the
    optional extra ``jaxgfx[volumes]``): ``.mha``, ``.nii``, ``.nii.gz``, ``.hdr``, ``.img``,
    ``.gipl`` and ``.gipl.gz``, and ``.mhd`` /
    NRRD files whose data is compressed or inside the header.

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
    ext = volume_suffix(path)
    if ext == ".vtk":
        return load_vtk_structured_points(path)
    if ext in SIMPLEITK_SUFFIXES:
        return load_with_simpleitk(path)
    if ext == ".mhd":
        h = _read_header(path)
        if h.get("elementdatafile", "").upper() == "LOCAL" or (
            h.get("compresseddata", "false").lower() == "true"
        ):
            return load_with_simpleitk(path)
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
        spec = h.get("data file", h.get("datafile"))
        if h.get("encoding", "raw") != "raw" or spec is None:
            return load_with_simpleitk(path)  # compressed or attached data
        dtype = dtype.newbyteorder(">" if h.get("endian", "little") == "big" else "<")
        spacing = _nrrd_spacing(h, path)
        parts = spec.split()
        if "%" in parts[0] and len(parts) >= 4:
            lo, hi, step = int(parts[1]), int(parts[2]), int(parts[3])
            files = [os.path.join(d, parts[0] % i) for i in range(lo, hi + 1, step)]
        else:
            files = [os.path.join(d, parts[0])]
    else:
        raise ValueError(
            f"path: unknown volume extension of {os.path.basename(path)!r} (want "
            f"{', '.join(VOLUME_SUFFIXES)}, or with jaxgfx[volumes] "
            f"{', '.join(SIMPLEITK_SUFFIXES)})"
        )
    if len(dims) != 3:
        raise ValueError(f"path: volume must be 3-D, header gives dims {dims}")
    vol = _read_raw(files, dims, dtype, "path")
    return vol.astype(dtype.newbyteorder("=")), np.asarray(spacing[:3], np.float64)


def volume_to_voxels(
    volume,
    iso: float | None = None,
    *,
    up_axis: int | str = 1,
    spacing=None,
    resolution: int | None = None,
) -> Voxels:
    """Thresholds a scanned volume at an iso value and keeps its surface (4.3.2).

    With ``spacing`` (or ``resolution``) the volume is first resampled to cubic
    voxels (:func:`~jaxgfx.raycast.resample_isotropic`: trilinear, the voxel
    edge is the finest spacing, or the longest physical axis split into
    ``resolution`` voxels), so a scan keeps its proportions.  Voxels with
    ``value >= iso`` are solid.  The colour is a gradient over the value above the
    iso level (dark brown to light green, as the thesis does to emphasize leaves in
    the bonsai).

    Args:
        volume: (X, Y, Z) scalar volume.
        iso: threshold, strictly inside the data range; None: Otsu's threshold of
            the volume's values (:func:`~jaxgfx.raycast.otsu_threshold`,
            the boundary between air and the scanned object).
        up_axis: which volume axis becomes world +y: 0, 1, 2 (x, y, z) or one of
            ``'x'``, ``'y'``, ``'z'``, ``'-x'``, ``'-y'``, ``'-z'``; the volume is
            rotated (not mirrored), e.g. z up maps ``(x, y, z)`` to ``(x, z, -y)``.
        spacing: optional (3,) sample spacing per volume axis (before ``up_axis``).
        resolution: optional voxel count of the longest physical axis.

    Returns:
        The surface :class:`Voxels`; the grid is the volume's (resampled) grid with
        ``up_axis`` turned to y.
    """
    vol = np.asarray(volume)
    if vol.ndim != 3:
        raise ValueError(f"volume must be 3-D, got shape {vol.shape}")
    turn_up(np.empty((1, 1, 1)), up_axis)  # checks up_axis before any work
    lo, hi = float(vol.min()), float(vol.max())
    if iso is None:
        iso = otsu_threshold(vol)
    if not (np.isfinite(iso) and lo < iso <= hi):
        raise ValueError(f"iso {iso} outside the data range ({lo}, {hi}]")
    if spacing is not None or resolution is not None:
        vol = resample_isotropic(vol, np.ones(3) if spacing is None else spacing, resolution)
    vol = turn_up(vol, up_axis)
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
    return make_voxels(coords, _bgra_to_rgb(c.astype(np.uint32)), (sx, height, sy))


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
    return make_voxels(coords, _bgra_to_rgb(color), (xs, zs, ys))


# ---------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------


def save_scene(path: str, vox: Voxels) -> None:
    """Writes voxels to an ``.npz`` atomically (temp file in the same folder, then replace).

    Args:
        path: the ``.npz`` file.
        vox: :class:`Voxels`; an :class:`~jaxgfx.raycast.RLEVolume` is saved as
            its level 0 (:func:`~jaxgfx.raycast.decode_rle`), a 3-D occupancy
            array as its surface voxels (:func:`~jaxgfx.raycast.dense_to_voxels`).
    """
    from jaxgfx._src.io import atomic_write
    from jaxgfx._src.voxel.encode import RLEVolume, decode_rle

    vox = decode_rle(vox) if isinstance(vox, RLEVolume) else as_voxels(vox)
    with atomic_write(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(
                fh, coords=vox.coords, colors=vox.colors, shape=np.asarray(vox.shape, np.int64)
            )


def load_scene(path: str) -> Voxels:
    """Reads voxels written by :func:`save_scene`.

    Raises:
        ValueError: ``path`` is missing, a directory, or not an ``.npz`` of a scene (a mesh,
            a volume or any other file is named as not a scene).
    """
    if not os.path.exists(path):
        raise ValueError(f"scene: {path!r} not found")
    if os.path.isdir(path):
        raise ValueError(f"scene: {path!r} is a directory, expected a scene .npz")
    try:
        z = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError):
        z = None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(
            f"scene: {path!r} is not a scene .npz (written by save_scene or 'jaxgfx voxelize')"
        )
    with z:
        try:
            return Voxels(
                z["coords"].astype(np.int32),
                z["colors"].astype(np.uint8),
                tuple(int(s) for s in z["shape"]),
            )
        except KeyError as e:
            raise ValueError(f"scene: {path!r} lacks array {e}") from None
