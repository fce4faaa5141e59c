"""Coloured voxel sets: the form every input takes (thesis 4.3), dense grids and surfaces.

:class:`Voxels` is a plain list of coloured voxels with its grid size.  Every importer
(:mod:`.voxelize`, :mod:`.formats`, :mod:`.tree`) returns one, keeping only the surface
voxels (Fig. 4.10): a ray from outside can hit no other.  :func:`downsample_voxels`
makes one mip level (4.4.7).

Conventions: scene coordinates are voxel units, y up; voxel ``(x, y, z)`` occupies
``[x, x+1) x [y, y+1) x [z, z+1)``.  Everything here is NumPy pre-processing.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxgfx._src.checks import check_int

__all__ = [
    "MAX_VOXELS",
    "Voxels",
    "make_voxels",
    "surface_mask",
    "dense_to_voxels",
    "as_voxels",
    "voxels_to_dense",
    "surface_voxels",
    "crop_voxels",
    "downsample_voxels",
]

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
    """A grid resolution as an int >= 1 whose cube stays below ``8 MAX_VOXELS``."""
    resolution = check_int("resolution", resolution, low=1)
    if resolution**3 > MAX_VOXELS * 8:
        raise ValueError(f"resolution {resolution} is absurdly large (grid > 2^34 voxels)")
    return resolution


def _check_shape(shape) -> tuple:
    shape = tuple(int(s) for s in shape)
    if len(shape) != 3 or min(shape) <= 0:
        raise ValueError(f"shape must be three positive ints, got {shape}")
    return shape


def _keys(coords, shape):
    """Linear index ``(x Y + y) Z + z`` of every coordinate (int64)."""
    X, Y, Z = shape
    c = np.asarray(coords, np.int64)
    return (c[:, 0] * Y + c[:, 1]) * Z + c[:, 2]


def make_voxels(coords, colors, shape) -> Voxels:
    """A :class:`Voxels` from coordinates and colours: dedupes (first colour wins), sorts.

    The order is by column ``(x, z)``, then top to bottom (``-y``); every importer
    builds its result through this.

    Args:
        coords: (N, 3) integer ``(x, y, z)``, inside ``shape``.
        colors: (N, 3) RGB, converted to uint8.
        shape: ``(X, Y, Z)`` grid size.
    """
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


def dense_to_voxels(occupancy, colors=None, *, surface: bool = True) -> Voxels:
    """Dense grid -> :class:`Voxels`, keeping only surface voxels by default.

    Args:
        occupancy: (X, Y, Z) bool (other dtypes: non-zero is solid).
        colors: (X, Y, Z, 3) uint8 RGB, or anything that broadcasts to it (one (3,)
            colour for all); None: the clay colour of ``voxelize_mesh`` (``CLAY``).
        surface: drop voxels that have no empty 6-neighbour.
    """
    occ = np.asarray(occupancy)
    if occ.ndim != 3:
        raise ValueError(f"occupancy must be 3-D (X, Y, Z), got shape {occ.shape}")
    occ = occ.astype(bool)
    if colors is None:
        from jaxgfx._src.voxel.voxelize import CLAY

        colors = np.asarray(CLAY, np.uint8)
    try:
        np.broadcast_to(np.asarray(colors), occ.shape + (3,))
    except ValueError:
        raise ValueError(
            f"colors must broadcast to {occ.shape + (3,)} (one RGB per voxel, or one for "
            f"all), got shape {np.shape(colors)}"
        ) from None
    mask = surface_mask(occ) if surface else occ
    idx = np.argwhere(mask)
    col = np.broadcast_to(np.asarray(colors, np.uint8), occ.shape + (3,))[mask]
    return make_voxels(idx, col, occ.shape)


def as_voxels(value, name: str = "vox") -> Voxels:
    """``value`` as :class:`Voxels`: Voxels pass, a 3-D occupancy array is converted.

    A dense (X, Y, Z) array (bool, or non-zero = solid) becomes its surface voxels in the
    clay colour (:func:`dense_to_voxels`); anything else is refused with a ``TypeError``
    that names the functions making :class:`Voxels`.

    Args:
        value: :class:`Voxels` or a 3-D array.
        name: the argument's name in the error message.
    """
    if isinstance(value, Voxels):
        return value
    if isinstance(value, tuple) and len(value) == 3 and not hasattr(value, "_fields"):
        coords, colors, shape = value
        return Voxels(np.asarray(coords), np.asarray(colors), tuple(shape))
    if hasattr(value, "level_shapes"):
        raise TypeError(
            f"{name} is an RLEVolume (already encoded); decode_rle(rle) gives its Voxels"
        )
    if hasattr(value, "shape") and hasattr(value, "dtype"):
        if np.ndim(value) == 3:
            return dense_to_voxels(np.asarray(value))
        raise TypeError(
            f"{name} must be Voxels or a 3-D occupancy array (X, Y, Z), got an array of "
            f"shape {np.shape(value)}; make_voxels(coords, colors, shape) builds Voxels "
            "from coordinates"
        )
    raise TypeError(
        f"{name} must be Voxels (from make_voxels, dense_to_voxels, voxelize_mesh, "
        f"load_scene, ...) or a 3-D occupancy array, got {type(value).__name__}"
    )


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


# ---------------------------------------------------------------------------
# 4.4.7 One mip level
# ---------------------------------------------------------------------------


def downsample_voxels(vox: Voxels, *, vertical: bool = True) -> Voxels:
    """One mip level (4.4.7): a coarse voxel is set where any of its 2x2x2 children is.

    Its colour is the mean of the set children.  ``vertical=False``: 2x1x2 children
    (x and z halved, y kept), for column mips.
    """
    f = np.array([2, 2 if vertical else 1, 2], np.int64)
    shape = tuple(int((s + k - 1) // k) for s, k in zip(vox.shape, f, strict=True))
    c = np.asarray(vox.coords, np.int64) // f
    k = _keys(c, shape)
    uk, inv, cnt = np.unique(k, return_inverse=True, return_counts=True)
    acc = np.zeros((len(uk), 3), np.float64)
    np.add.at(acc, inv, vox.colors.astype(np.float64))
    col = np.round(acc / cnt[:, None]).astype(np.uint8)
    X, Y, Z = shape
    coords = np.stack([uk // (Y * Z), (uk // Z) % Y, uk % Z], axis=1)
    return make_voxels(coords, col, shape)
