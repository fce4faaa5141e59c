"""Terrains from data: height maps (thesis 3.5.2, Fig. 3.16) and binary volumes (3.3.1, 3.5.3).

A height map becomes a volume that is solid below the height of its cell; USGS ASCII
DEMs, ``.npy``/``.npz`` arrays and grey or RGB images are read by :func:`load_heightmap`.
An existing binary volume is placed in the world, optionally tiled in x and z.
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_int, static_field
from jaxgfx._src.terrain.functions import _I32, _floormod

__all__ = [
    "HeightmapTerrain",
    "load_heightmap",
    "heightmap_terrain",
    "VolumeTerrain",
    "volume_terrain",
]


# --------------------------------------------------------------------------------------
# Height maps (3.5.2)
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class HeightmapTerrain:
    """Height map -> volume (3.5.2, Fig. 3.16): solid where ``y < height(x, z)``, tiled.

    Attributes:
        heights: (H, W) int32 heights in voxels; row = z cell, column = x cell.
        cell: static int, voxels per height-map pixel horizontally.
    """

    heights: jax.Array
    cell: int = static_field(1)

    def __call__(self, p: jax.Array) -> jax.Array:
        p = jnp.asarray(p, _I32)
        rows, cols = self.heights.shape
        cx = _floormod(jnp.floor_divide(p[0], self.cell), cols)
        cz = _floormod(jnp.floor_divide(p[2], self.cell), rows)
        return p[1] < self.heights[cz, cx]


def _parse_usgs_dem(data: bytes, path: str) -> np.ndarray:
    """USGS ASCII DEM (type A header + type B profiles) -> (rows, cols) float64 metres."""
    header = data[:1024].decode("ascii", errors="replace")
    try:
        dy = float(header[828:840].replace("D", "E"))
        n_profiles = int(header[858:864])
        tokens = data[1024:].decode("ascii").replace("D", "E").split()
        pos = 0
        profiles = []
        for _ in range(n_profiles):
            m = int(tokens[pos + 2])
            y0 = float(tokens[pos + 5])
            elev = np.asarray(tokens[pos + 9 : pos + 9 + m], dtype=np.float64)
            if elev.size != m:
                raise ValueError("truncated profile")
            profiles.append((y0, elev))
            pos += 9 + m
    except (ValueError, IndexError, UnicodeDecodeError) as err:
        raise ValueError(f"heightmap {path!r} is not a readable USGS ASCII DEM: {err}") from None
    if not profiles or dy <= 0:
        raise ValueError(f"heightmap {path!r} has no elevation profiles")
    y_lo = min(p[0] for p in profiles)
    rows = max(int(round((p[0] - y_lo) / dy)) + p[1].size for p in profiles)
    grid = np.full((rows, len(profiles)), np.nan)
    for c, (y0, elev) in enumerate(profiles):
        r = int(round((y0 - y_lo) / dy))
        grid[r : r + elev.size, c] = elev
    # The DEM quad is rotated against UTM; fill the corners outside it with the lowest height.
    grid = np.where(np.isnan(grid), np.nanmin(grid), grid)
    return grid[::-1]  # north at row 0, like an image


def load_heightmap(path: str | os.PathLike) -> np.ndarray:
    """Reads a height map: USGS ASCII ``.dem``, ``.npy``/``.npz`` or a grey/RGB image.

    Returns:
        (H, W) float64 heights (file units; images give grey levels).

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: ``path`` is not a DEM or an image.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"heightmap path {path!r} does not exist")
    lower = path.lower()
    if lower.endswith(".dem"):
        with open(path, "rb") as fh:
            return _parse_usgs_dem(fh.read(), path)
    if lower.endswith((".npy", ".npz")):
        arr = np.load(path)
        if isinstance(arr, np.lib.npyio.NpzFile):
            arr = arr[arr.files[0]]
    else:
        import imageio.v3 as iio

        try:
            arr = iio.imread(path)
        except Exception as err:  # imageio raises many types for unreadable files
            raise ValueError(f"heightmap {path!r} is not an image or a DEM: {err}") from None
    arr = np.asarray(arr, np.float64)
    if arr.ndim == 3:
        arr = arr[..., :3].mean(axis=-1)
    if arr.ndim != 2 or min(arr.shape) < 1:
        raise ValueError(f"heightmap {path!r} must be 2-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"heightmap {path!r} contains non-finite values")
    return arr


def heightmap_terrain(
    heights, *, vertical_scale: float = 1.0, cell: int = 1, base: int = 0
) -> HeightmapTerrain:
    """Converts real heights to an integer :class:`HeightmapTerrain`.

    Args:
        heights: (H, W) heights, or a path given to :func:`load_heightmap`.
        vertical_scale: voxels per height unit.
        cell: voxels per pixel horizontally.
        base: voxel height of the lowest sample.
    """
    if isinstance(heights, (str, os.PathLike)):
        heights = load_heightmap(heights)
    h = np.asarray(heights, np.float64)
    if h.ndim != 2 or min(h.shape) < 1:
        raise ValueError(f"heights must be a non-empty 2-D array, got shape {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError("heights must be finite")
    if not np.isfinite(vertical_scale) or vertical_scale <= 0:
        raise ValueError(f"vertical_scale must be a positive number, got {vertical_scale}")
    check_int("cell", cell, low=1)
    hv = np.round((h - h.min()) * vertical_scale) + base
    if np.abs(hv).max() >= 2**31 - 1:
        raise ValueError("vertical_scale makes heights overflow int32")
    return HeightmapTerrain(heights=jnp.asarray(hv.astype(np.int32)), cell=int(cell))


# --------------------------------------------------------------------------------------
# Binary volumes (3.3.1, 3.5.3)
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class VolumeTerrain:
    """An existing binary volume placed in the world, optionally tiled (3.3.1, 3.5.3).

    Attributes:
        volume: (X, Y, Z) bool.
        offset: (3,) int32 world position of voxel (0, 0, 0).
        period: static (px, pz) tiling period in x and z, or None for one copy.
    """

    volume: jax.Array
    offset: jax.Array
    period: tuple[int, int] | None = static_field(None)

    def __call__(self, p: jax.Array) -> jax.Array:
        q = jnp.asarray(p, _I32) - self.offset
        if self.period is not None:
            q = q.at[0].set(_floormod(q[0], self.period[0]))
            q = q.at[2].set(_floormod(q[2], self.period[1]))
        shape = jnp.asarray(self.volume.shape, _I32)
        inside = jnp.all((q >= 0) & (q < shape))
        qc = jnp.clip(q, 0, shape - 1)
        return inside & self.volume[qc[0], qc[1], qc[2]]


def volume_terrain(volume, *, offset=(0, 0, 0), period: tuple[int, int] | None = None):
    """Builds a :class:`VolumeTerrain`; ``period`` (x, z) must be >= the volume's size."""
    vol = np.asarray(volume)
    if vol.ndim != 3 or min(vol.shape) < 1:
        raise ValueError(f"volume must be a non-empty 3-D array, got shape {vol.shape}")
    off = np.asarray(offset)
    if off.shape != (3,) or not np.issubdtype(off.dtype, np.integer):
        raise ValueError(f"offset must be 3 integers, got {offset!r}")
    if period is not None:
        period = (int(period[0]), int(period[1]))
        if period[0] < vol.shape[0] or period[1] < vol.shape[2]:
            raise ValueError(f"period {period} must be >= the volume's x/z size {vol.shape}")
    return VolumeTerrain(
        volume=jnp.asarray(vol.astype(bool)), offset=jnp.asarray(off, _I32), period=period
    )
