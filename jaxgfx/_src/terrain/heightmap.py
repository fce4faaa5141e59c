"""Terrains from data: height maps (thesis 3.5.2, Fig. 3.16) and binary volumes (3.3.1, 3.5.3).

A height map becomes a volume that is solid below a continuous surface.  The mapping
from samples to the world is one :class:`HeightmapMapping`: the sample in row ``r``,
column ``c`` with value ``v`` stands at

    x = origin_x + (c + 0.5) cell_x,   z = origin_z + (r + 0.5) cell_z,
    y = base + (v - min_value) vertical_scale,

and between sample centres the surface height ``H(x, z)`` is the bilinear interpolation
of the four nearest samples.  Beyond the map (unless it is tiled with ``wrap``) the
edge samples extend outwards and fade, over ``apron_fade`` voxels, to one flat level,
the median height of the map's border samples: a flat apron around the map instead
of edge profiles stretched into ridges to the horizon (see :func:`_apron`).  A voxel
``(x, y, z)`` (the unit cube with that lower corner) is solid iff its centre is below
the surface:

    solid(x, y, z)  <=>  y + 0.5 < H(x + 0.5, z + 0.5),

so the top solid voxel of a column is ``ceil(H - 0.5) - 1`` and :func:`ground_height` is
``H`` itself.  Levels sample the same function at every ``2^l``-th voxel, so fine levels
(cell > 1) see sloped ground, not terraces.

Elevation files are read by :func:`read_heightmap` (``elevation.py``), which also
returns what the file says about itself (metres between samples along x and z, the
height unit); :func:`heightmap_terrain` uses that for true proportions, the same
metres per voxel on x, y and z.  An existing binary volume is placed in the world,
optionally tiled in x and z.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_float, static_field
from jaxgfx._src.terrain.elevation import (
    HeightmapData,
    load_heightmap,
    read_heightmap,
)
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
    "IMAGE_RELIEF",
    "APRON_FADE",
]

_F32 = jnp.float32
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
_REACH = 2**30
"""Voxel coordinates are clipped to +-2^30 around the map before subtracting its origin:
no int32 overflow, and beyond the map the apron is flat anyway."""
IMAGE_RELIEF = 0.125
"""Files without units (images, arrays): the samples' range spans this fraction of the
map's longer side (at most its shorter side), whatever the bit depth -- the proportion
of real mountain maps (St Helens: 1.86 km of relief on 14 km)."""
APRON_FADE = 0.05
"""Beyond the map the edge fades to the flat apron over this fraction of the map's
longer side (at least two samples): short enough that edge profiles do not run on as
ridges, long enough that the map does not end in a cliff."""
# --------------------------------------------------------------------------------------
# Height maps placed in the world (3.5.2)
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class HeightmapMapping:
    """Where a height map's samples stand in the world (hashable; a static field).

    The sample in row ``r``, column ``c`` with value ``v`` stands at
    ``x = origin[0] + (c + 0.5) cell``, ``z = origin[1] + (r + 0.5) cell_z``,
    ``y = base + (v - min_value) vertical_scale`` (world voxel units, y up).

    Attributes:
        origin: (x, z) world position of pixel (0, 0)'s outer corner, voxels.
        cell: voxels per sample along x.
        vertical_scale: voxels per height unit.
        base: world y of the minimum value.
        shape: (rows, cols) of the height map.
        min_value: the map's minimum value (file units).
        wrap: True tiles the map with period ``(cols cell, rows cell_z)``; False
            surrounds it with the flat apron.
        cell_z: voxels per sample along z; None: ``cell`` (square samples).
        apron_height: voxels above ``base`` of the flat apron around the map.
        apron_fade: voxels beyond the edge over which the edge fades into the apron.
        metres_per_sample: (x, z) metres between samples, when the file says.
        height_unit: metres per height unit, when the file says.
        crs: the file's grid, e.g. ``"EPSG:4326"``, when it says.
        nodata: samples the file marked NODATA (voids), filled from their neighbours.
    """

    origin: tuple[float, float]
    cell: float
    vertical_scale: float
    base: float
    shape: tuple[int, int]
    min_value: float
    wrap: bool = False
    cell_z: float | None = None
    apron_height: float = 0.0
    apron_fade: float = 1.0
    metres_per_sample: tuple[float, float] | None = None
    height_unit: float | None = None
    crs: str | None = None
    nodata: int = 0

    @property
    def cells(self) -> tuple[float, float]:
        """(x, z) voxels per sample."""
        return (self.cell, self.cell if self.cell_z is None else self.cell_z)

    @property
    def metres_per_voxel(self) -> tuple[float, float, float] | None:
        """(x, y, z) metres per voxel of the built terrain, when the file gives units."""
        if self.metres_per_sample is None or self.height_unit is None:
            return None
        cx, cz = self.cells
        mx, mz = self.metres_per_sample
        return (mx / cx, self.height_unit / self.vertical_scale, mz / cz)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able mapping: ``origin``, ``cell`` [x, z], ``vertical_scale``, ``base``,
        ``shape``; ``edge`` (``"apron"`` with ``apron``'s world y and fade, or
        ``"wrap"``); the scale: ``metres_per_sample`` [x, z] read from the file and
        ``metres_per_voxel`` [x, y, z] of the terrain built (None without units), the
        file's ``crs``, and ``nodata``: ``count``, the samples the file marked NODATA (filled
        from their neighbours), and ``fraction``, their share of the map."""

        def r(v):
            return None if v is None else [round(float(a), 6) for a in v]

        out: dict[str, Any] = {
            "origin": [float(self.origin[0]), float(self.origin[1])],
            "cell": [float(c) for c in self.cells],
            "vertical_scale": float(self.vertical_scale),
            "base": float(self.base),
            "shape": [int(self.shape[0]), int(self.shape[1])],
            "edge": "wrap" if self.wrap else "apron",
        }
        if not self.wrap:
            out["apron"] = {
                "y": float(self.base + self.apron_height),
                "fade": float(self.apron_fade),
            }
        out["metres_per_sample"] = r(self.metres_per_sample)
        out["metres_per_voxel"] = r(self.metres_per_voxel)
        out["crs"] = self.crs
        total = int(self.shape[0]) * int(self.shape[1])
        out["nodata"] = {"count": int(self.nodata), "fraction": round(self.nodata / total, 6)}
        return out

    def sample_position(self, rows, cols, values) -> np.ndarray:
        """World (x, y, z) of samples: ``rows``, ``cols``, ``values`` broadcast -> (..., 3)."""
        r, c, v = np.broadcast_arrays(
            np.asarray(rows, np.float64), np.asarray(cols, np.float64), np.asarray(values)
        )
        cx, cz = self.cells
        x = self.origin[0] + (c + 0.5) * cx
        z = self.origin[1] + (r + 0.5) * cz
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


def _apron(m: HeightmapMapping, u: jax.Array, v: jax.Array) -> jax.Array:
    """Weight of the flat apron at fractional sample (column, row) ``(u, v)``, in [0, 1].

    0 on the map (within the outer sample centres' half cell), rising with the
    smoothstep of the distance beyond it over ``apron_fade`` voxels, 1 from there on.
    The distance is Euclidean in voxels, so the corners fade round, not along streaks.
    """
    rows, cols = m.shape
    cx, cz = m.cells
    ex = jnp.maximum(jnp.maximum(-0.5 - u, u - (cols - 0.5)), 0.0) * _F32(cx)
    ez = jnp.maximum(jnp.maximum(-0.5 - v, v - (rows - 0.5)), 0.0) * _F32(cz)
    fade = _F32(m.apron_fade)
    ex, ez = jnp.minimum(ex, fade), jnp.minimum(ez, fade)
    t = jnp.minimum(jnp.sqrt(ex * ex + ez * ez) / fade, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _surface(heights: jax.Array, m: HeightmapMapping, u: jax.Array, v: jax.Array) -> jax.Array:
    """``H - base`` at fractional sample (column, row) ``(u, v)``: the map, tiled or in
    its apron."""
    h = _bilinear(heights, u, v, m.wrap)
    if m.wrap:
        return h
    w = _apron(m, u, v)
    return h * (1.0 - w) + _F32(m.apron_height) * w


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
        cx, cz = m.cells
        u = self._axis_coord(x, m.origin[0], m.shape[1], cx)
        v = self._axis_coord(z, m.origin[1], m.shape[0], cz)
        return _surface(self.heights, m, u, v)

    def _axis_coord(
        self, a: jax.Array, origin: float, count: int, cell: float, frac=0.5
    ) -> jax.Array:
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
            period = int(round(count * cell))
            d = _floormod(_floormod(a, period) - (oi % period), period)
        else:
            d = _int_offset(a, oi)
        rest = _F32(frac - of) if isinstance(frac, float) else frac - _F32(of)
        return (d.astype(_F32) + rest) / _F32(cell) - _F32(0.5)

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
        cx, cz = m.cells
        u = self._axis_coord(origin[0], m.origin[0], m.shape[1], cx, vertices[:, 0])
        v = self._axis_coord(origin[2], m.origin[1], m.shape[0], cz, vertices[:, 2])
        h = _surface(self.heights, m, u, v)
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
    apron_fade: float | None = None,
) -> HeightmapTerrain:
    """Places a height map in the world as a :class:`HeightmapTerrain` (3.5.2).

    Files with units (GeoTIFF, SRTM ``.hgt``, ESRI ``.asc``, USGS ``.dem``) get true
    proportions: one metres-per-voxel on x, y and z.  ``cell`` voxels per sample along
    x fixes it (``metres_per_sample[0] / cell``); the z cell and the vertical scale
    follow (3 arc-seconds at 36.6 N, 74.6 m by 92.5 m: cell_z = 1.24 cell).  Files without
    units (images, arrays) get square cells and a relief (max - min) of
    :data:`IMAGE_RELIEF` of the map's longer side, at most its shorter side, whatever
    the bit depth; set ``vertical_scale`` to taste.

    Args:
        heights_or_path: (H, W) heights, a :class:`HeightmapData`, or a path for
            :func:`read_heightmap`.
        cell: voxels per sample along x (> 0); default 1.
        vertical_scale: voxels per height unit (> 0); default as above.
        origin: (x, z) world position of pixel (0, 0)'s corner; default centres the map
            on the world origin (rounded to whole voxels).
        base: world y of the map's minimum value.
        wrap: tile the map with period ``(W cell_x, H cell_z)`` (which must be whole
            voxels); default False surrounds it with a flat apron at the median height
            of its border samples.
        apron_fade: voxels beyond the edge over which the edge fades into the apron
            (> 0); default :data:`APRON_FADE` of the map's longer side.

    Returns:
        A :class:`HeightmapTerrain`; its ``mapping`` says where every sample stands and
        the scale (``mapping.to_dict()``).

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
    spacing = data.spacing
    if spacing is not None and not isinstance(spacing, (tuple, list, np.ndarray)):
        spacing = (float(spacing), float(spacing))
    units = spacing is not None and data.height_unit is not None
    rows, cols = h.shape
    rng = float(h.max() - h.min())
    if units:
        mx, mz = (float(a) for a in spacing)  # type: ignore[union-attr]
        if not (mx > 0 and mz > 0):
            raise ValueError(f"the file's sample spacing must be > 0, got {spacing}")
        metres = mx / cell  # per voxel, on every axis
        cell_z = mz / metres
        if vertical_scale is None:
            vertical_scale = float(data.height_unit) / metres  # type: ignore[arg-type]
    else:
        cell_z = cell
        if vertical_scale is None:
            long, short = max(rows, cols) * cell, min(rows, cols) * cell
            relief = min(IMAGE_RELIEF * long, short)
            vertical_scale = relief / rng if rng > 0 else cell
    vertical_scale = check_float("vertical_scale", vertical_scale)
    if vertical_scale <= 0:
        raise ValueError(f"vertical_scale must be > 0, got {vertical_scale}")
    base = check_float("base", base)
    width, depth = cols * cell, rows * cell_z
    if origin is None:
        origin = (-math.floor(width / 2), -math.floor(depth / 2))
    if len(origin) != 2:
        raise ValueError(f"origin must be (x, z), got {origin!r}")
    origin = (check_float("origin[0]", origin[0]), check_float("origin[1]", origin[1]))
    if max(abs(origin[0]), abs(origin[1]), abs(base)) >= _REACH:
        raise ValueError(f"origin {origin} and base {base} must be within +-2^30 voxels")
    if wrap:
        for n, c, axis in ((cols, cell, "x"), (rows, cell_z, "z")):
            if abs(n * c - round(n * c)) > 1e-9 * n * c or round(n * c) < 1:
                raise ValueError(
                    f"cell {cell} with wrap=True must make the {axis} period {n} * {c:g} "
                    "a whole number of voxels"
                )
    if apron_fade is None:
        apron_fade = max(APRON_FADE * max(width, depth), 2.0 * max(cell, cell_z))
    apron_fade = check_float("apron_fade", apron_fade)
    if apron_fade <= 0:
        raise ValueError(f"apron_fade must be > 0, got {apron_fade}")
    rel = (h - h.min()) * vertical_scale
    if rel.max() + abs(base) >= 2**24:
        raise ValueError(
            f"vertical_scale {vertical_scale} makes the relief {rel.max():.3g} voxels "
            "(float32 heights need < 2^24)"
        )
    border = np.concatenate([rel[0], rel[-1], rel[:, 0], rel[:, -1]])
    mapping = HeightmapMapping(
        origin=origin,
        cell=cell,
        vertical_scale=vertical_scale,
        base=base,
        shape=(int(rows), int(cols)),
        min_value=float(h.min()),
        wrap=bool(wrap),
        cell_z=None if cell_z == cell else float(cell_z),
        apron_height=float(np.float32(np.median(border))),
        apron_fade=float(apron_fade),
        metres_per_sample=(mx, mz) if units else None,
        height_unit=float(data.height_unit) if units else None,  # type: ignore[arg-type]
        crs=data.crs,
        nodata=int(data.nodata),
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
    cx, cz = m.cells
    x, z = jnp.broadcast_arrays(jnp.asarray(x, _F32), jnp.asarray(z, _F32))
    u = (x - _F32(m.origin[0])) / _F32(cx) - _F32(0.5)
    v = (z - _F32(m.origin[1])) / _F32(cz) - _F32(0.5)
    return _F32(m.base) + _surface(terrain.heights, m, u, v)


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
    cx, cz = m.cells
    if height is None:
        relief = float(np.max(np.asarray(terrain.heights)))
        width = max(m.shape[1] * cx, m.shape[0] * cz)
        height = min(max(8.0, relief / 2), max(8.0, width / 4))
    height = check_float("height", height, low=0)
    x = math.floor(m.origin[0] + m.shape[1] * cx / 2)
    z = math.floor(m.origin[1] + m.shape[0] * cz / 2)
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
