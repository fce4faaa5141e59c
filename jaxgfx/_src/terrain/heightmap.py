"""Terrains from data: height maps (thesis 3.5.2, Fig. 3.16) and binary volumes (3.3.1, 3.5.3).

A height map becomes a volume that is solid below a continuous surface.  The mapping
from samples to the world is one :class:`HeightmapMapping`: the sample in row ``r``,
column ``c`` with value ``v`` stands at

    x = origin_x + (c + 0.5) cell,   z = origin_z + (r + 0.5) cell,
    y = base + (v - min_value) vertical_scale,

and between sample centres the surface height ``H(x, z)`` is the bilinear interpolation
of the four nearest samples (edges clamped, or tiled with ``wrap``).  A voxel ``(x, y, z)``
(the unit cube with that lower corner) is solid iff its centre is below the surface:

    solid(x, y, z)  <=>  y + 0.5 < H(x + 0.5, z + 0.5),

so the top solid voxel of a column is ``ceil(H - 0.5) - 1`` and :func:`ground_height` is
``H`` itself.  Levels sample the same function at every ``2^l``-th voxel, so fine levels
(cell > 1) see sloped ground, not terraces.

USGS ASCII DEMs, ``.npy``/``.npz`` arrays and grey or RGB images are read by
:func:`read_heightmap`, which also returns what the file says about itself (horizontal
spacing, elevation unit); :func:`heightmap_terrain` uses that for true proportions.
An existing binary volume is placed in the world, optionally tiled in x and z.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_float, static_field
from jaxgfx._src.terrain.functions import _I32, _floormod

__all__ = [
    "HeightmapData",
    "read_heightmap",
    "load_heightmap",
    "HeightmapMapping",
    "HeightmapTerrain",
    "heightmap_terrain",
    "ground_height",
    "default_viewer",
    "VolumeTerrain",
    "volume_terrain",
]

_F32 = jnp.float32
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
_REACH = 2**30
"""Voxel coordinates are clipped to +-2^30 around the map before subtracting its origin:
no int32 overflow, and beyond the map the clamped surface is the same anyway."""
_METRES_PER_FOOT = 0.3048
_METRES_PER_ARC_SECOND = 30.87
"""One arc-second of latitude; geographic DEMs give their spacing in arc-seconds."""


# --------------------------------------------------------------------------------------
# Reading height maps
# --------------------------------------------------------------------------------------


class HeightmapData(NamedTuple):
    """A height-map file: its samples and what the file says about them.

    Attributes:
        heights: (H, W) float64 values as the file gives them (DEM: elevations in the
            file's elevation unit; images: grey levels, RGB averaged; arrays: as stored).
            Row 0 is north (the image's top row).
        spacing: horizontal distance between samples in metres, or None when the file
            does not say (images, arrays).
        height_unit: metres per height unit (1.0 for metres, 0.3048 for feet), or None.
    """

    heights: np.ndarray
    spacing: float | None
    height_unit: float | None


def _header_int(header: str, a: int, b: int) -> int | None:
    try:
        return int(header[a:b])
    except ValueError:
        return None


def _fill_outside(grid: np.ndarray) -> np.ndarray:
    """NaN cells take the mean of their known 4-neighbours, ring by ring (outwards).

    A USGS DEM's quad is rotated against the UTM grid, so profiles start and end at
    different rows and the grid's corners outside the quad have no samples.  Growing
    the known samples outwards extends the edge as the clamped map edge does beyond
    the map; the lowest height (the old fill) dug a moat around the map and a cliff
    along the quad's slanted sides.
    """
    grid = grid.copy()
    known = ~np.isnan(grid)
    if not known.any():
        raise ValueError("no samples")
    while not known.all():
        val = np.pad(np.where(known, grid, 0.0), 1)
        cnt = np.pad(known.astype(np.float64), 1)
        total = val[:-2, 1:-1] + val[2:, 1:-1] + val[1:-1, :-2] + val[1:-1, 2:]
        n = cnt[:-2, 1:-1] + cnt[2:, 1:-1] + cnt[1:-1, :-2] + cnt[1:-1, 2:]
        grow = ~known & (n > 0)
        grid[grow] = total[grow] / n[grow]
        known = known | grow
    return grid


def _parse_usgs_dem(data: bytes, path: str) -> HeightmapData:
    """USGS ASCII DEM (type A header + type B profiles) -> heights and spacing.

    Type A record fields (0-based byte ranges): ground unit 528:534 (0 radians,
    1 feet, 2 metres, 3 arc-seconds), elevation unit 534:540 (1 feet, 2 metres),
    spatial resolution x, y, z 816:852 (3 x E12.6), profile count 858:864.  Each
    type B profile holds 9 header tokens (row, column, m, n, x, y, local datum,
    min, max) and m elevations; elevation = datum + value * z resolution.
    """
    header = data[:1024].decode("ascii", errors="replace")
    try:
        dx = float(header[816:828].replace("D", "E"))
        dy = float(header[828:840].replace("D", "E"))
        dz = float(header[840:852].replace("D", "E"))
        n_profiles = int(header[858:864])
        tokens = data[1024:].decode("ascii").replace("D", "E").split()
        pos = 0
        profiles = []
        for _ in range(n_profiles):
            m = int(tokens[pos + 2])
            y0 = float(tokens[pos + 5])
            datum = float(tokens[pos + 6])
            elev = np.asarray(tokens[pos + 9 : pos + 9 + m], dtype=np.float64)
            if elev.size != m:
                raise ValueError("truncated profile")
            profiles.append((y0, datum + elev * (dz if dz > 0 else 1.0)))
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
    grid = _fill_outside(grid)
    # Rows are spaced dy, columns dx; the DEMs we know have dx == dy, one cell serves both.
    ground = {1: _METRES_PER_FOOT, 2: 1.0, 3: _METRES_PER_ARC_SECOND}.get(
        _header_int(header, 528, 534) or -1
    )
    spacing = None if ground is None or dx <= 0 else float(math.sqrt(dx * dy) * ground)
    unit = {1: _METRES_PER_FOOT, 2: 1.0}.get(_header_int(header, 534, 540) or -1)
    return HeightmapData(grid[::-1], spacing, unit)  # north at row 0, like an image


def read_heightmap(path: str | os.PathLike) -> HeightmapData:
    """Reads a height map and what its file says: USGS ASCII ``.dem``, ``.npy``/``.npz``, image.

    A DEM gives its horizontal spacing and elevation unit (type A header); images and
    arrays give neither (``spacing`` and ``height_unit`` are None).

    Returns:
        :class:`HeightmapData` with (H, W) float64 ``heights``.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: ``path`` is not a DEM, an array or an image, or is not 2-D and finite.
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
    return HeightmapData(arr, None, None)


def load_heightmap(path: str | os.PathLike) -> np.ndarray:
    """The (H, W) float64 heights of :func:`read_heightmap` (file units, grey levels)."""
    return read_heightmap(path).heights


# --------------------------------------------------------------------------------------
# Height maps placed in the world (3.5.2)
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class HeightmapMapping:
    """Where a height map's samples stand in the world (hashable; a static field).

    The sample in row ``r``, column ``c`` with value ``v`` stands at
    ``x = origin[0] + (c + 0.5) cell``, ``z = origin[1] + (r + 0.5) cell``,
    ``y = base + (v - min_value) vertical_scale`` (world voxel units, y up).

    Attributes:
        origin: (x, z) world position of pixel (0, 0)'s outer corner, voxels.
        cell: voxels per pixel horizontally.
        vertical_scale: voxels per height unit.
        base: world y of the minimum value.
        shape: (rows, cols) of the height map.
        min_value: the map's minimum value (file units).
        wrap: True tiles the map with period ``shape * cell``; False clamps its edges.
    """

    origin: tuple[float, float]
    cell: float
    vertical_scale: float
    base: float
    shape: tuple[int, int]
    min_value: float
    wrap: bool = False

    def to_dict(self) -> dict[str, Any]:
        """JSON-able ``{origin, cell, vertical_scale, base, shape, edge}``: issue 17's keys
        and what lies beyond the map (``"clamp"``: the edge samples extend outwards;
        ``"wrap"``: the map repeats)."""
        return {
            "origin": [float(self.origin[0]), float(self.origin[1])],
            "cell": float(self.cell),
            "vertical_scale": float(self.vertical_scale),
            "base": float(self.base),
            "shape": [int(self.shape[0]), int(self.shape[1])],
            "edge": "wrap" if self.wrap else "clamp",
        }

    def sample_position(self, rows, cols, values) -> np.ndarray:
        """World (x, y, z) of samples: ``rows``, ``cols``, ``values`` broadcast -> (..., 3)."""
        r, c, v = np.broadcast_arrays(
            np.asarray(rows, np.float64), np.asarray(cols, np.float64), np.asarray(values)
        )
        x = self.origin[0] + (c + 0.5) * self.cell
        z = self.origin[1] + (r + 0.5) * self.cell
        y = self.base + (v.astype(np.float64) - self.min_value) * self.vertical_scale
        return np.stack([x, y, z], axis=-1)


def _int_offset(a: jax.Array, o: int) -> jax.Array:
    """``a - o`` for int32 ``a``, with ``a`` clipped to ``o +- 2^30`` (no int32 overflow)."""
    lo, hi = max(o - _REACH, _INT32_MIN), min(o + _REACH, _INT32_MAX)
    return jnp.clip(a, lo, hi) - jnp.asarray(o, _I32)


def _bilinear(heights: jax.Array, u: jax.Array, v: jax.Array, wrap: bool) -> jax.Array:
    """Bilinear ``heights`` at fractional (column, row) ``(u, v)``, clamped or wrapped."""
    rows, cols = heights.shape
    if not wrap:
        # beyond the edge every index clamps to it: keep the int32 cast in range
        u = jnp.clip(u, -1.0, float(cols))
        v = jnp.clip(v, -1.0, float(rows))
    u0, v0 = jnp.floor(u), jnp.floor(v)
    fu, fv = u - u0, v - v0
    c0, r0 = u0.astype(_I32), v0.astype(_I32)
    c1, r1 = c0 + 1, r0 + 1
    if wrap:
        c0, c1, r0, r1 = (
            _floormod(c0, cols),
            _floormod(c1, cols),
            _floormod(r0, rows),
            _floormod(r1, rows),
        )
    else:
        c0, c1 = jnp.clip(c0, 0, cols - 1), jnp.clip(c1, 0, cols - 1)
        r0, r1 = jnp.clip(r0, 0, rows - 1), jnp.clip(r1, 0, rows - 1)
    top = heights[r0, c0] * (1 - fu) + heights[r0, c1] * fu
    bottom = heights[r1, c0] * (1 - fu) + heights[r1, c1] * fu
    return top * (1 - fv) + bottom * fv


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class HeightmapTerrain:
    """Height map -> volume (3.5.2, Fig. 3.16): solid where ``y + 0.5 < H(x + 0.5, z + 0.5)``.

    ``H`` is the bilinear surface of the module docstring; build with
    :func:`heightmap_terrain`.

    Attributes:
        heights: (H, W) float32 voxels above ``mapping.base``:
            ``(value - min_value) * vertical_scale``; row = z, column = x.
        mapping: static :class:`HeightmapMapping`.
    """

    heights: jax.Array
    mapping: HeightmapMapping = static_field()

    def _column_height(self, x: jax.Array, z: jax.Array) -> jax.Array:
        """Float32 ``H - base`` at the centre of the int32 voxel column ``(x, z)``."""
        m = self.mapping
        u = self._axis_coord(x, m.origin[0], m.shape[1])
        v = self._axis_coord(z, m.origin[1], m.shape[0])
        return _bilinear(self.heights, u, v, m.wrap)

    def _axis_coord(self, a: jax.Array, origin: float, count: int, frac=0.5) -> jax.Array:
        """Fractional sample index of the world point ``a + frac`` along one axis.

        ``a`` is int32 (``frac = 0.5``: the centre of voxel ``a``; an array: float32
        offsets).  The integer part of ``origin`` is subtracted in int32 (exact at
        10^9); with ``wrap`` it is first reduced modulo the period, which is a whole
        number of voxels.
        """
        m = self.mapping
        oi = math.floor(origin)
        of = origin - oi
        a = jnp.asarray(a, _I32)
        if m.wrap:
            period = int(round(count * m.cell))
            d = _floormod(_floormod(a, period) - (oi % period), period)
        else:
            d = _int_offset(a, oi)
        rest = _F32(frac - of) if isinstance(frac, float) else frac - _F32(of)
        return (d.astype(_F32) + rest) / _F32(m.cell) - _F32(0.5)

    def snap_to_surface(self, origin: jax.Array, vertices: jax.Array) -> jax.Array:
        """Mesh vertices moved vertically onto the surface ``y = H(x, z)`` (3.4.7).

        A height map knows its surface, so after the voxel mesh is smoothed each vertex
        takes the height of the bilinear surface under it: the levels' quantisation
        (up to half a ``2^l`` voxel) and smoothing's shrinkage of ridges and valleys
        go away, and every level becomes the same heightfield sampled at its own
        lattice (vertical voxel walls collapse to zero-area triangles).

        Args:
            origin: (3,) int32 world position the vertices are relative to (a box origin).
            vertices: (V, 3) float32 positions relative to ``origin``.
        Returns:
            (V, 3) float32: x and z unchanged, y on the surface (relative to ``origin``).
        """
        m = self.mapping
        origin = jnp.asarray(origin, _I32)
        u = self._axis_coord(origin[0], m.origin[0], m.shape[1], vertices[:, 0])
        v = self._axis_coord(origin[2], m.origin[1], m.shape[0], vertices[:, 2])
        h = _bilinear(self.heights, u, v, m.wrap)
        # y - origin_y = H - base + (base - origin_y); the int parts cancel in int32
        bi = math.floor(m.base)
        dy = _int_offset(origin[1], bi).astype(_F32) - _F32(m.base - bi)
        return vertices.at[:, 1].set(h - dy)

    def _height_above_base(self, y: jax.Array) -> jax.Array:
        """Float32 ``y + 0.5 - base`` for int32 voxel rows ``y`` (exact for any int32)."""
        bi = math.floor(self.mapping.base)
        return _int_offset(jnp.asarray(y, _I32), bi).astype(_F32) + _F32(
            0.5 - (self.mapping.base - bi)
        )

    def __call__(self, p: jax.Array) -> jax.Array:
        p = jnp.asarray(p, _I32)
        return self._height_above_base(p[1]) < self._column_height(p[0], p[2])

    def sample_grid(self, origin: jax.Array, level: int, shape: tuple[int, int, int]):
        """The grid ``origin + i 2^level``: one surface height per column, not per voxel.

        Equal to ``vmap(self)`` on the same points (same arithmetic); the fast path of
        :func:`jaxgfx.terrain.sample_terrain`.
        """
        origin = jnp.asarray(origin, _I32)
        axes = [origin[k] + (jnp.arange(shape[k], dtype=_I32) << level) for k in range(3)]
        cols = jax.vmap(lambda x: jax.vmap(lambda z: self._column_height(x, z))(axes[2]))(axes[0])
        rows = self._height_above_base(axes[1])
        return rows[None, :, None] < cols[:, None, :]


def heightmap_terrain(
    heights_or_path,
    *,
    cell: float | None = None,
    vertical_scale: float | None = None,
    origin: tuple[float, float] | None = None,
    base: float = 0,
    wrap: bool = False,
) -> HeightmapTerrain:
    """Places a height map in the world as a :class:`HeightmapTerrain` (3.5.2).

    Defaults give true proportions where the file says them: a USGS DEM's horizontal
    spacing and elevation unit make ``vertical_scale = cell * metres_per_unit / spacing``
    (St Helens: 30 m pixels, metres -> cell / 30 voxels per metre).  Images and arrays
    say nothing, so one height unit (grey level) is one pixel's width:
    ``vertical_scale = cell`` (one grey level per voxel at cell 1); set it to taste.

    Args:
        heights_or_path: (H, W) heights, a :class:`HeightmapData`, or a path for
            :func:`read_heightmap`.
        cell: voxels per pixel horizontally (> 0); default 1.
        vertical_scale: voxels per height unit (> 0); default as above.
        origin: (x, z) world position of pixel (0, 0)'s corner; default centres the map
            on the world origin (rounded to whole voxels).
        base: world y of the map's minimum value.
        wrap: tile the map with period ``(W cell, H cell)`` (which must be whole voxels);
            default False clamps the edges (the edge samples extend outwards).

    Returns:
        A :class:`HeightmapTerrain`; its ``mapping`` says where every sample stands.

    Raises:
        ValueError: naming the argument that is empty, non-finite, out of range.
        TypeError: ``wrap`` is not a bool.
    """
    if isinstance(heights_or_path, (str, os.PathLike)):
        heights_or_path = read_heightmap(heights_or_path)
    if isinstance(heights_or_path, HeightmapData):
        data = heights_or_path
    else:
        data = HeightmapData(np.asarray(heights_or_path), None, None)
    h = np.asarray(data.heights, np.float64)
    if h.ndim != 2 or min(h.shape) < 1:
        raise ValueError(f"heights must be a non-empty 2-D array, got shape {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError("heights must be finite")
    if not isinstance(wrap, (bool, np.bool_)):
        raise TypeError(f"wrap must be a bool, got {type(wrap).__name__}")
    cell = 1.0 if cell is None else check_float("cell", cell)
    if cell <= 0:
        raise ValueError(f"cell must be > 0, got {cell}")
    if vertical_scale is None:
        if data.spacing and data.height_unit:
            vertical_scale = cell * data.height_unit / data.spacing
        else:
            vertical_scale = cell
    vertical_scale = check_float("vertical_scale", vertical_scale)
    if vertical_scale <= 0:
        raise ValueError(f"vertical_scale must be > 0, got {vertical_scale}")
    base = check_float("base", base)
    rows, cols = h.shape
    if origin is None:
        origin = (-math.floor(cols * cell / 2), -math.floor(rows * cell / 2))
    if len(origin) != 2:
        raise ValueError(f"origin must be (x, z), got {origin!r}")
    origin = (check_float("origin[0]", origin[0]), check_float("origin[1]", origin[1]))
    if max(abs(origin[0]), abs(origin[1]), abs(base)) >= _REACH:
        raise ValueError(f"origin {origin} and base {base} must be within +-2^30 voxels")
    if wrap:
        for n, axis in ((cols, "x"), (rows, "z")):
            if abs(n * cell - round(n * cell)) > 1e-9 * n * cell or round(n * cell) < 1:
                raise ValueError(
                    f"cell {cell} with wrap=True must make the {axis} period {n} * cell "
                    "a whole number of voxels"
                )
    rel = (h - h.min()) * vertical_scale
    if rel.max() + abs(base) >= 2**24:
        raise ValueError(
            f"vertical_scale {vertical_scale} makes the relief {rel.max():.3g} voxels "
            "(float32 heights need < 2^24)"
        )
    mapping = HeightmapMapping(
        origin=origin,
        cell=cell,
        vertical_scale=vertical_scale,
        base=base,
        shape=(int(rows), int(cols)),
        min_value=float(h.min()),
        wrap=bool(wrap),
    )
    return HeightmapTerrain(heights=jnp.asarray(rel, _F32), mapping=mapping)


def _check_heightmap(terrain) -> HeightmapTerrain:
    if not isinstance(terrain, HeightmapTerrain):
        raise TypeError(f"terrain must be a HeightmapTerrain, got {type(terrain).__name__}")
    return terrain


def ground_height(terrain: HeightmapTerrain, x, z) -> jax.Array:
    """World y of the surface ``H(x, z)`` at world ``(x, z)`` (float voxels, jnp, vmap-able).

    The surface the voxel function uses: voxel column ``(i, k)`` is solid up to
    ``ceil(ground_height(terrain, i + 0.5, k + 0.5) - 0.5) - 1``, so an object whose
    base stands at ``ground_height`` touches the top of the voxels (within one voxel).
    ``x`` and ``z`` are float32; beyond ~2^24 voxels from the map use the voxel function.

    Args:
        terrain: a :class:`HeightmapTerrain`.
        x: world x, any shape (broadcast with ``z``).
        z: world z.
    Returns:
        float32 heights of the broadcast shape.
    """
    terrain = _check_heightmap(terrain)
    m = terrain.mapping
    x, z = jnp.broadcast_arrays(jnp.asarray(x, _F32), jnp.asarray(z, _F32))
    u = (x - _F32(m.origin[0])) / _F32(m.cell) - _F32(0.5)
    v = (z - _F32(m.origin[1])) / _F32(m.cell) - _F32(0.5)
    return _F32(m.base) + _bilinear(terrain.heights, u, v, m.wrap)


def default_viewer(terrain: HeightmapTerrain, height: float | None = None) -> tuple[int, int, int]:
    """An integer viewer ``(x, y, z)`` above the map centre, ``height`` voxels over the ground.

    Args:
        terrain: a :class:`HeightmapTerrain`.
        height: voxels above the top solid voxel at the centre; default half the map's
            relief, at least 8 and at most a quarter of the map's width.
    Returns:
        (x, y, z) Python ints; ``terrain`` is air there.
    """
    terrain = _check_heightmap(terrain)
    m = terrain.mapping
    if height is None:
        relief = float(np.max(np.asarray(terrain.heights)))
        width = max(m.shape) * m.cell
        height = min(max(8.0, relief / 2), max(8.0, width / 4))
    height = check_float("height", height, low=0)
    x = math.floor(m.origin[0] + m.shape[1] * m.cell / 2)
    z = math.floor(m.origin[1] + m.shape[0] * m.cell / 2)
    g = float(ground_height(terrain, x + 0.5, z + 0.5))
    top = math.ceil(g - 0.5)  # the first air voxel of the column
    return int(x), int(top + math.ceil(height)), int(z)


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
