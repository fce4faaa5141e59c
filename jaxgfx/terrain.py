"""Procedural volumetric terrain with nested Clip-Boxes (thesis chapter 3).

A terrain is a function ``f: Z^3 -> {0, 1}`` (Eq. 3.1): it takes one integer
world coordinate ``(x, y, z)`` (int32, y up) and returns a bool (solid or air).
Every terrain here is a frozen dataclass pytree with ``__call__(p)`` written for
ONE point; sampling batches it with ``jax.vmap``.  World coordinates are int32
voxel indices of the finest level, so the terrain is the same, exactly, at
x = 0 and at x = 10^9; floats only appear relative to a box origin or to the
viewer (thesis 3.5.3, "unlimited terrain size").

A Clip-Box (3.4.1-3.4.2) of level ``l`` holds ``N^3`` voxels of edge ``2^l``
whose origin is snapped to the ``2^(l+1)`` lattice, so each box's boundary lies
on the lattice of the next outer box and boxes nest concentrically about the
viewer (3.4.5).  Moving a box reuses the overlap and samples only the newly
exposed slabs (3.4.6, Fig. 3.11).

Voxels become quads on faces between solid and air voxels with shared lattice
vertices (3.4.4, Fig. 3.8).  Seams between levels (Fig. 3.6-3.7) are closed in
two steps: the outermost ring (one outer voxel thick) of an inner box takes its
occupancy from the outer lattice samples, and the inner boundary vertices that
sit between two outer lattice vertices are snapped onto the outer lattice; after
smoothing, the inner boundary vertices take the outer mesh's positions
(:func:`weld_seam`).  The union of an inner mesh and the outer mesh minus the
inner region (:func:`visible_faces`) is then closed along the seam.
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "XorTerrain",
    "SawTerrain",
    "SinTerrain",
    "CSGTerrain",
    "HeightmapTerrain",
    "VolumeTerrain",
    "FunctionTerrain",
    "Union",
    "Intersection",
    "Difference",
    "PRIMITIVE_SPHERE",
    "PRIMITIVE_BOX",
    "PRIMITIVE_CYLINDER",
    "as_terrain",
    "check_terrain",
    "random_csg_terrain",
    "csg_terrain",
    "load_heightmap",
    "heightmap_terrain",
    "volume_terrain",
    "ClipBox",
    "clipbox_origin",
    "sample_terrain",
    "sample_clipbox",
    "shift_clipbox",
    "reused_fraction",
    "slab_thickness",
    "pattern_filter",
    "ClipBoxMesh",
    "voxels_to_mesh",
    "smooth_mesh",
    "mesh_normals",
    "weld_seam",
    "visible_faces",
    "subdivide_mesh",
    "SubdividedMesh",
    "NestedClipBoxes",
    "nested_origins",
    "ClipBoxPipeline",
    "GeometryWorker",
    "render_levels",
    "level_views",
    "level_arrays",
    "int_sin",
    "mesh_to_trimesh",
]

_I32 = jnp.int32


def _static():
    return dataclasses.field(metadata=dict(static=True))


def _floormod(a, m):
    """Mathematical (floor) modulo for int32 arrays; the sign follows ``m``."""
    return jnp.remainder(a, m)


# --------------------------------------------------------------------------------------
# Terrain functions (3.4.3, 3.5.3, Eq. 3.1-3.2)
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class XorTerrain:
    """``f_XOR(x, y, z) = ((x xor y xor z) mod modulus < threshold)`` (Eq. 3.2).

    ``mod`` is the mathematical (floor) modulo, exact on int32 (the xor of
    sign-extended int32 values equals the sign extension of the int32 xor).
    """

    modulus: int = dataclasses.field(default=1000, metadata=dict(static=True))
    threshold: int = dataclasses.field(default=357, metadata=dict(static=True))

    def __call__(self, p: jax.Array) -> jax.Array:
        p = jnp.asarray(p, _I32)
        v = jnp.bitwise_xor(jnp.bitwise_xor(p[0], p[1]), p[2])
        return _floormod(v, self.modulus) < self.threshold


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SawTerrain:
    """``f_SAW(x, y, z) = ((x + y + z) mod modulus < threshold)`` (Eq. 3.2).

    Each coordinate is reduced first, so the sum never overflows int32 and the
    result equals the exact integer value for every int32 coordinate.
    """

    modulus: int = dataclasses.field(default=1000, metadata=dict(static=True))
    threshold: int = dataclasses.field(default=500, metadata=dict(static=True))

    def __call__(self, p: jax.Array) -> jax.Array:
        r = _floormod(jnp.asarray(p, _I32), self.modulus)
        return _floormod(r[0] + r[1] + r[2], self.modulus) < self.threshold


def _sin_cos_tables() -> tuple[np.ndarray, np.ndarray]:
    """sin/cos of ``h 2^20``, ``m 2^10`` and ``l`` (float64 -> float32), stacked (3, 4096)."""
    h = np.arange(-2048, 2048, dtype=np.float64) * 2.0**20
    m = np.arange(1024, dtype=np.float64) * 2.0**10
    l_ = np.arange(1024, dtype=np.float64)
    pad = lambda a: np.concatenate([a, np.zeros(4096 - a.size)])  # noqa: E731
    ang = [h, pad(m), pad(l_)]
    # np.sin of an exactly representable float64 integer is correctly reduced by libm.
    return (
        np.stack([np.sin(a) for a in ang]).astype(np.float32),
        np.stack([np.cos(a) for a in ang]).astype(np.float32),
    )


def int_sin(x: jax.Array) -> jax.Array:
    """``sin(x)`` of an int32 ``x`` with absolute error ~3e-7 for every int32.

    ``x = h 2^20 + m 2^10 + l`` exactly; the three angles come from float64
    tables and are combined with the angle-addition formula, so the accuracy does
    not degrade far from the origin (a float32 ``sin(1e9)`` would be meaningless).
    """
    x = jnp.asarray(x, _I32)
    s_tab, c_tab = _sin_cos_tables()
    s_tab, c_tab = jnp.asarray(s_tab), jnp.asarray(c_tab)
    h = jnp.right_shift(x, 20) + 2048
    m = jnp.bitwise_and(jnp.right_shift(x, 10), 1023)
    lo = jnp.bitwise_and(x, 1023)
    sh, ch = s_tab[0, h], c_tab[0, h]
    sm, cm = s_tab[1, m], c_tab[1, m]
    sl, cl = s_tab[2, lo], c_tab[2, lo]
    s_hm = sh * cm + ch * sm
    c_hm = ch * cm - sh * sm
    return s_hm * cl + c_hm * sl


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SinTerrain:
    """``f_SIN(x, y, z) = (sin x + sin y + sin z < threshold)`` (Eq. 3.2), integer arguments."""

    threshold: float = dataclasses.field(default=2.0, metadata=dict(static=True))

    def __call__(self, p: jax.Array) -> jax.Array:
        p = jnp.asarray(p, _I32)
        return int_sin(p[0]) + int_sin(p[1]) + int_sin(p[2]) < self.threshold


PRIMITIVE_SPHERE = 0
PRIMITIVE_BOX = 1
PRIMITIVE_CYLINDER = 2


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CSGTerrain:
    """Ordered CSG of integer primitives, tiled in x and z, with spatial bins (3.4.3, Fig. 3.5).

    The terrain starts as ``y < ground`` and primitive ``i = 0, 1, ...`` is added
    (union) or carved out (difference) in order.  The result at a point is
    therefore decided by the LAST primitive containing it: solid if that one is a
    union, air if a difference, the ground otherwise -- an order-free reduction
    over the primitives of the point's bin, so a point costs O(bin occupancy),
    not O(primitives).

    Attributes:
        centers: (P, 3) int32 primitive centres; x, z in [0, period).
        extents: (P, 3) int32 sphere (r, r, r); box half sizes; cylinder (r, half height, r).
        kinds: (P,) int32 ``PRIMITIVE_*``.
        union: (P,) bool, True adds material, False carves.
        bins: (Bx * By * Bz + 1, K) int32 primitive ids per bin in increasing
            order, -1 padded; the last row is the empty bin for points outside
            the y range.
        period: static int, tiling period in x and z (voxels).
        bin_size: static int, bin edge (voxels).
        y_min: static int, lowest y of the bins.
        bins_y: static int, number of bins along y.
        ground: static int, points with ``y < ground`` start solid.
    """

    centers: jax.Array
    extents: jax.Array
    kinds: jax.Array
    union: jax.Array
    bins: jax.Array
    period: int = _static()
    bin_size: int = _static()
    y_min: int = _static()
    bins_y: int = _static()
    ground: int = _static()

    def __call__(self, p: jax.Array) -> jax.Array:
        p = jnp.asarray(p, _I32)
        nxz = self.period // self.bin_size
        px = _floormod(p[0], self.period)
        pz = _floormod(p[2], self.period)
        by = jnp.floor_divide(p[1] - self.y_min, self.bin_size)
        in_y = (by >= 0) & (by < self.bins_y)
        b = (jnp.clip(by, 0, self.bins_y - 1) * nxz + px // self.bin_size) * nxz + (
            pz // self.bin_size
        )
        b = jnp.where(in_y, b, self.bins.shape[0] - 1)
        ids = self.bins[b]  # (K,)
        valid = ids >= 0
        safe = jnp.where(valid, ids, 0)
        c = self.centers[safe]
        e = self.extents[safe]
        half = self.period // 2
        # Periodic displacement in x/z; y is clipped so squares never overflow int32
        # (anything that far is outside every primitive anyway).
        dx = _floormod(px - c[:, 0] + half, self.period) - half
        dz = _floormod(pz - c[:, 2] + half, self.period) - half
        dy = jnp.clip(p[1] - c[:, 1], -(1 << 14), 1 << 14)
        k = self.kinds[safe]
        in_sphere = dx * dx + dy * dy + dz * dz <= e[:, 0] * e[:, 0]
        in_box = (jnp.abs(dx) <= e[:, 0]) & (jnp.abs(dy) <= e[:, 1]) & (jnp.abs(dz) <= e[:, 2])
        in_cyl = (dx * dx + dz * dz <= e[:, 0] * e[:, 0]) & (jnp.abs(dy) <= e[:, 1])
        inside = valid & jnp.where(
            k == PRIMITIVE_SPHERE, in_sphere, jnp.where(k == PRIMITIVE_BOX, in_box, in_cyl)
        )
        # Bin lists are sorted, so the largest slot that contains p is the last primitive.
        slot = jnp.arange(ids.shape[0], dtype=_I32)
        last = jnp.max(jnp.where(inside, slot, -1))
        last_union = self.union[safe][jnp.maximum(last, 0)]
        return jnp.where(last >= 0, last_union, p[1] < self.ground)

    def sample_grid(self, origin: jax.Array, level: int, shape: tuple[int, int, int]):
        """The grid ``origin + i 2^level`` in one pass per bin slot (fast path of 3.4.3).

        With a voxel smaller than a bin, ``s = bin_size / 2^level`` consecutive
        voxels along each axis share a bin, so the box is evaluated on the
        bin-aligned super-grid of shape ``(G s)^3`` whose bins' primitives are
        gathered once (G^3 K records) and broadcast over each bin's ``s^3``
        voxels -- no per-voxel gathers, which dominate the per-point path on
        XLA:CPU.  Slots are visited in order (later primitives win) only up to the
        fullest local bin.  Equal to ``vmap(self)`` on the same points.

        Args:
            origin: (3,) int32 world coordinate of sample (0, 0, 0).
            level: static int.
            shape: static grid shape.
        Returns:
            ``shape`` bool.  Only the rows inside the bins' y range are evaluated;
            where fewer than 2 voxels share a bin, those rows go point by point.
        """
        step = 1 << level
        origin = jnp.asarray(origin, _I32)
        # Only rows inside the bins' y range need primitives; the rest is ground.
        n_y = shape[1]
        lo = self.y_min
        rows = min(n_y, -(-(self.bins_y * self.bin_size) // step) + 1)
        start = jnp.clip(-jnp.floor_divide(origin[1] - lo, step), 0, n_y - rows)
        band_origin = origin.at[1].add(start * step)
        band_shape = (shape[0], rows, shape[2])
        if 2 * step > self.bin_size or self.bin_size % step:
            band = _sample_points(self, band_origin, level, band_shape)
        else:
            band = self._sample_shared_bins(band_origin, step, band_shape)
        if rows == n_y:
            return band
        y = origin[1] + jnp.arange(n_y, dtype=_I32) * step
        ground = jnp.broadcast_to((y < self.ground)[None, :, None], tuple(shape))
        return jax.lax.dynamic_update_slice(ground, band, (0, start, 0))

    def _sample_shared_bins(self, origin, step: int, shape):
        """Bin-aligned super-grid evaluation (see :meth:`sample_grid`); needs 2 step <= bin."""
        bs = self.bin_size
        s = bs // step
        world, first, offset = [], [], []
        for d, n in enumerate(shape):
            u = origin[d] - (self.y_min if d == 1 else 0)
            b0 = jnp.floor_divide(u, bs)
            off = jnp.floor_divide(u - b0 * bs, step)  # first voxel's place in its bin
            g = (n + 2 * s - 2) // s  # bins spanned by n voxels at any offset
            world.append((origin[d] + (jnp.arange(g * s, dtype=_I32) - off) * step).reshape(g, s))
            first.append(b0 + jnp.arange(g, dtype=_I32))
            offset.append(off)
        nxz = self.period // bs
        bx = _floormod(first[0], nxz)[:, None, None]
        by = first[1][None, :, None]
        bz = _floormod(first[2], nxz)[None, None, :]
        b = (jnp.clip(by, 0, self.bins_y - 1) * nxz + bx) * nxz + bz
        b = jnp.where((by >= 0) & (by < self.bins_y), b, self.bins.shape[0] - 1)
        ids = self.bins[b]  # (Gx, Gy, Gz, K)
        valid = ids >= 0
        safe = jnp.where(valid, ids, 0)
        # Records per (bin, slot), laid out to broadcast over (Gx, s, Gy, s, Gz, s).
        rec = jnp.concatenate(
            [
                self.centers[safe],
                self.extents[safe],
                self.kinds[safe][..., None],
                jnp.where(valid, self.union[safe], False)[..., None].astype(_I32),
                valid[..., None].astype(_I32),
            ],
            axis=-1,
        )  # (Gx, Gy, Gz, K, 9)
        rec = jnp.moveaxis(rec, 3, 0)[:, :, None, :, None, :, None, :]
        px = _floormod(world[0], self.period)[:, :, None, None, None, None]
        py = world[1][None, None, :, :, None, None]
        pz = _floormod(world[2], self.period)[None, None, None, None, :, :]
        half, period = self.period // 2, self.period

        def wrap(dv):  # exact periodic displacement in [-half, half): |dv| < period
            return jnp.where(dv >= half, dv - period, jnp.where(dv < -half, dv + period, dv))

        def slot(k, solid):
            r = jax.lax.dynamic_index_in_dim(rec, k, axis=0, keepdims=False)
            c0, c1, c2, e0, e1, e2, kind, union, ok = (r[..., i] for i in range(9))
            dx, dz = wrap(px - c0), wrap(pz - c2)
            dy = jnp.clip(py - c1, -(1 << 14), 1 << 14)
            r2 = dx * dx + dz * dz
            in_sphere = r2 + dy * dy <= e0 * e0
            in_box = (jnp.abs(dx) <= e0) & (jnp.abs(dy) <= e1) & (jnp.abs(dz) <= e2)
            in_cyl = (r2 <= e0 * e0) & (jnp.abs(dy) <= e1)
            shape_in = jnp.where(
                kind == PRIMITIVE_SPHERE,
                in_sphere,
                jnp.where(kind == PRIMITIVE_BOX, in_box, in_cyl),
            )
            return jnp.where((ok == 1) & shape_in, union == 1, solid)

        full = tuple(g.shape[0] * s for g in world)
        grid6 = jnp.broadcast_shapes(px.shape, py.shape, pz.shape)
        solid = jnp.broadcast_to(py < self.ground, grid6)
        # Bounded by K; stops after the fullest local bin (boolean output, no gradient).
        used = jnp.max(jnp.sum(valid, axis=-1))
        solid = jax.lax.fori_loop(0, used, slot, solid)
        return jax.lax.dynamic_slice(solid.reshape(full), tuple(offset), tuple(shape))


def csg_terrain(
    centers,
    extents,
    kinds,
    union,
    *,
    period: int,
    y_range: tuple[int, int],
    bin_size: int = 16,
    ground: int = 0,
) -> CSGTerrain:
    """Builds a binned :class:`CSGTerrain` from explicit integer primitives (host side).

    Args:
        centers: (P, 3) ints; x and z are taken modulo ``period``.
        extents: (P, 3) positive ints (see :class:`CSGTerrain`).
        kinds: (P,) ints in ``PRIMITIVE_*``.
        union: (P,) bools.
        period: tiling period in x and z, a multiple of ``bin_size``.
        y_range: ``(y_min, y_max)``; every primitive must lie inside it.
        bin_size: bin edge in voxels.
        ground: ``y < ground`` is solid before the first primitive.
    """
    centers = np.asarray(centers, np.int64).reshape(-1, 3)
    extents = np.asarray(extents, np.int64).reshape(-1, 3)
    kinds = np.asarray(kinds, np.int64).reshape(-1)
    union = np.asarray(union, bool).reshape(-1)
    n = centers.shape[0]
    if not (extents.shape[0] == kinds.shape[0] == union.shape[0] == n):
        raise ValueError(
            f"centers, extents, kinds, union must have the same length, got "
            f"{n}, {extents.shape[0]}, {kinds.shape[0]}, {union.shape[0]}"
        )
    for name, v in (("period", period), ("bin_size", bin_size)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ValueError(f"{name} must be a positive int, got {v!r}")
    if period % bin_size:
        raise ValueError(f"period ({period}) must be a multiple of bin_size ({bin_size})")
    if period > (1 << 14):
        raise ValueError(f"period must be <= {1 << 14} so squared distances fit int32")
    if np.any(extents <= 0) or np.any(extents >= (1 << 13)):
        raise ValueError("extents must be in [1, 8191]")
    if np.any((kinds < 0) | (kinds > 2)):
        raise ValueError("kinds must be PRIMITIVE_SPHERE, PRIMITIVE_BOX or PRIMITIVE_CYLINDER")
    y_min, y_max = int(y_range[0]), int(y_range[1])
    if y_max <= y_min:
        raise ValueError(f"y_range must be (y_min, y_max) with y_max > y_min, got {y_range}")
    reach = np.where(kinds[:, None] == PRIMITIVE_SPHERE, extents[:, :1], extents)
    reach = np.where(
        (kinds[:, None] == PRIMITIVE_CYLINDER) & (np.arange(3) != 1), reach[:, :1], reach
    )
    if n and (
        np.any(centers[:, 1] - reach[:, 1] < y_min) or np.any(centers[:, 1] + reach[:, 1] >= y_max)
    ):
        raise ValueError(f"every primitive must lie inside y_range {y_range}")
    if n and np.any(2 * reach[:, [0, 2]] + 1 > period):
        raise ValueError("primitives must be smaller than the period")
    centers = centers.copy()
    centers[:, [0, 2]] %= period
    nxz = period // bin_size
    bins_y = -(-(y_max - y_min) // bin_size)
    lists: list[list[int]] = [[] for _ in range(bins_y * nxz * nxz)]
    for i in range(n):
        lo = centers[i] - reach[i]
        hi = centers[i] + reach[i]
        xs = range(lo[0] // bin_size, hi[0] // bin_size + 1)
        ys = range((lo[1] - y_min) // bin_size, (hi[1] - y_min) // bin_size + 1)
        zs = range(lo[2] // bin_size, hi[2] // bin_size + 1)
        cells = {(bx % nxz, by, bz % nxz) for bx in xs for by in ys for bz in zs}
        for bx, by, bz in cells:
            lists[(by * nxz + bx) * nxz + bz].append(i)
    k = max(1, max((len(v) for v in lists), default=1))
    table = np.full((len(lists) + 1, k), -1, np.int32)
    for b, v in enumerate(lists):
        table[b, : len(v)] = v  # appended in increasing primitive order
    return CSGTerrain(
        centers=jnp.asarray(centers, _I32),
        extents=jnp.asarray(extents, _I32),
        kinds=jnp.asarray(kinds, _I32),
        union=jnp.asarray(union),
        bins=jnp.asarray(table),
        period=int(period),
        bin_size=int(bin_size),
        y_min=y_min,
        bins_y=int(bins_y),
        ground=int(ground),
    )


def random_csg_terrain(
    *,
    key: jax.Array,
    count: int = 50_000,
    period: int = 4096,
    y_range: tuple[int, int] = (-128, 256),
    radius: tuple[int, int] = (4, 24),
    union_fraction: float = 0.6,
    kind_weights: tuple[float, float, float] = (0.5, 0.25, 0.25),
    bin_size: int = 16,
    ground: int = 0,
) -> CSGTerrain:
    """Random CSG terrain (3.4.3): ``count`` primitives drawn from ``key`` in user ranges.

    Centres are uniform in the ``period x (y range) x period`` tile; sizes are
    uniform integers in ``radius``; ``union_fraction`` of the operations add
    material, the rest carve caves, arches and overhangs.  The thesis's benchmark
    terrain has about 50 000 Boolean operations (3.5.2).  Smaller bins mean fewer
    primitives tested per point (16: at most 8 for the default ranges) but a
    larger table (16: 1.6 M bins, 50 MB for the defaults).
    """
    if count < 0:
        raise ValueError(f"count must be >= 0, got {count}")
    r0, r1 = int(radius[0]), int(radius[1])
    if not 1 <= r0 <= r1:
        raise ValueError(f"radius must be (min, max) with 1 <= min <= max, got {radius}")
    if not 0.0 <= union_fraction <= 1.0:
        raise ValueError(f"union_fraction must be in [0, 1], got {union_fraction}")
    y_min, y_max = int(y_range[0]), int(y_range[1])
    if y_max - y_min <= 2 * r1 + 1:
        raise ValueError(f"y_range {y_range} is too small for radius {radius}")
    w = np.asarray(kind_weights, np.float64)
    if w.shape != (3,) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"kind_weights must be 3 non-negative weights, got {kind_weights}")
    k_xz, k_y, k_r, k_kind, k_op = jax.random.split(key, 5)
    xz = jax.random.randint(k_xz, (count, 2), 0, period)
    y = jax.random.randint(k_y, (count,), y_min + r1 + 1, y_max - r1 - 1)
    ext = jax.random.randint(k_r, (count, 3), r0, r1 + 1)
    kinds = jax.random.choice(k_kind, 3, (count,), p=jnp.asarray(w / w.sum()))
    union = jax.random.uniform(k_op, (count,)) < union_fraction
    centers = np.stack([np.asarray(xz[:, 0]), np.asarray(y), np.asarray(xz[:, 1])], axis=1)
    return csg_terrain(
        centers,
        np.asarray(ext),
        np.asarray(kinds),
        np.asarray(union),
        period=period,
        y_range=(y_min, y_max),
        bin_size=bin_size,
        ground=ground,
    )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class HeightmapTerrain:
    """Height map -> volume (3.5.2, Fig. 3.16): solid where ``y < height(x, z)``, tiled.

    Attributes:
        heights: (H, W) int32 heights in voxels; row = z cell, column = x cell.
        cell: static int, voxels per height-map pixel horizontally.
    """

    heights: jax.Array
    cell: int = dataclasses.field(default=1, metadata=dict(static=True))

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
    if isinstance(cell, bool) or not isinstance(cell, (int, np.integer)) or cell < 1:
        raise ValueError(f"cell must be a positive int, got {cell!r}")
    hv = np.round((h - h.min()) * vertical_scale) + base
    if np.abs(hv).max() >= 2**31 - 1:
        raise ValueError("vertical_scale makes heights overflow int32")
    return HeightmapTerrain(heights=jnp.asarray(hv.astype(np.int32)), cell=int(cell))


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
    period: tuple[int, int] | None = dataclasses.field(default=None, metadata=dict(static=True))

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


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FunctionTerrain:
    """Wraps a user callable ``fn(p: int32 (3,)) -> bool ()`` (static, hashed by identity)."""

    fn: Callable[[jax.Array], jax.Array] = _static()

    def __call__(self, p: jax.Array) -> jax.Array:
        return self.fn(p)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Union:
    """``a or b``."""

    a: Any
    b: Any

    def __call__(self, p):
        return self.a(p) | self.b(p)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Intersection:
    """``a and b``."""

    a: Any
    b: Any

    def __call__(self, p):
        return self.a(p) & self.b(p)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Difference:
    """``a and not b``."""

    a: Any
    b: Any

    def __call__(self, p):
        return self.a(p) & ~self.b(p)


_TERRAIN_TYPES = (
    XorTerrain,
    SawTerrain,
    SinTerrain,
    CSGTerrain,
    HeightmapTerrain,
    VolumeTerrain,
    FunctionTerrain,
    Union,
    Intersection,
    Difference,
)


def as_terrain(terrain) -> Any:
    """Returns ``terrain`` as a pytree terrain (plain callables are wrapped)."""
    if isinstance(terrain, _TERRAIN_TYPES):
        return terrain
    if callable(terrain):
        return FunctionTerrain(fn=terrain)
    raise TypeError(f"terrain must be a terrain object or a callable, got {type(terrain).__name__}")


def check_terrain(terrain, name: str = "terrain") -> Any:
    """Validates a terrain before tracing: one int32 (3,) point must give a bool scalar.

    Raises:
        TypeError: naming ``name`` when the output has the wrong shape or dtype.
    """
    terrain = as_terrain(terrain)
    try:
        out = jax.eval_shape(terrain, jax.ShapeDtypeStruct((3,), _I32))
    except Exception as err:
        raise TypeError(f"{name} failed on one int32 (3,) point: {err}") from err
    if not isinstance(out, jax.ShapeDtypeStruct) or out.shape != () or out.dtype != jnp.bool_:
        got = (getattr(out, "shape", None), getattr(out, "dtype", type(out).__name__))
        raise TypeError(
            f"{name} must map one int32 (3,) point to a bool scalar (Eq. 3.1), "
            f"got shape/dtype {got}"
        )
    return terrain


# --------------------------------------------------------------------------------------
# Clip-Box sampling and the differential update (3.4.1-3.4.3, 3.4.6)
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ClipBox:
    """One Clip-Box level (3.4.1-3.4.2).

    Attributes:
        origin: (3,) int32 world coordinate of voxel (0, 0, 0); a multiple of 2^(level+1).
        voxels: (N, N, N) bool, indexed [x, y, z]; voxel i samples ``origin + i 2^level``.
        level: () int32, voxel edge is ``2^level`` (a leaf, so one compilation of
            the meshing steps serves every level).
        size: static int, N.
    """

    origin: jax.Array
    voxels: jax.Array
    level: jax.Array
    size: int = _static()


def _check_size(size) -> int:
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)):
        raise TypeError(f"size must be an int, got {type(size).__name__}")
    if size < 8 or size % 8:
        raise ValueError(
            f"size (N) must be a multiple of 8 and >= 8 (even so boxes nest on the outer "
            f"lattice, /8 for the nesting margin), got {size}"
        )
    return int(size)


def _check_level(level) -> int:
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)):
        raise TypeError(f"level must be an int, got {type(level).__name__}")
    if not 0 <= level <= 20:
        raise ValueError(f"level must be in [0, 20], got {level}")
    return int(level)


def clipbox_origin(viewer, level: int, size: int) -> np.ndarray:
    """Origin of the level-``level`` box centred on ``viewer``, snapped to the 2^(level+1) grid.

    Args:
        viewer: (3,) integer world coordinate (host values).
    Returns:
        (3,) int64 origin.
    """
    level, size = _check_level(level), _check_size(size)
    v = np.asarray(viewer)
    if v.shape != (3,) or not np.issubdtype(v.dtype, np.integer):
        raise ValueError(f"viewer must be 3 integers, got {viewer!r}")
    step = 2 << level
    return np.floor_divide(v.astype(np.int64) - (size // 2) * (1 << level), step) * step


def _sample_points(terrain, origin, level, shape):
    idx = [jnp.arange(n, dtype=_I32) << level for n in shape]
    gx, gy, gz = jnp.meshgrid(*idx, indexing="ij")
    pts = jnp.stack([gx, gy, gz], axis=-1).reshape(-1, 3) + jnp.asarray(origin, _I32)
    return jax.vmap(terrain)(pts).reshape(shape)


def sample_terrain(terrain, origin: jax.Array, *, level, shape: tuple[int, int, int]):
    """Samples ``terrain`` at ``origin + i 2^level`` for i in ``shape`` (3.4.3).

    Terrains with a ``sample_grid(origin, level, shape)`` method (the binned CSG)
    take their grid fast path when ``level`` is a Python int; combinators recurse
    into their operands; everything else is ``vmap`` over the points.

    Args:
        terrain: a terrain pytree (validate with :func:`check_terrain` first).
        origin: (3,) int32 world coordinate of sample (0, 0, 0).
        level: voxel level: a static int (fast paths) or a () int32 (may be traced).
        shape: static grid shape.
    Returns:
        ``shape`` bool.
    """
    if isinstance(terrain, (Union, Intersection, Difference)):
        a = sample_terrain(terrain.a, origin, level=level, shape=shape)
        b = sample_terrain(terrain.b, origin, level=level, shape=shape)
        if isinstance(terrain, Union):
            return a | b
        return a & b if isinstance(terrain, Intersection) else a & ~b
    grid = getattr(terrain, "sample_grid", None)
    if grid is not None and isinstance(level, (int, np.integer)) and not isinstance(level, bool):
        out = grid(origin, int(level), tuple(shape))
        if out is not None:
            return out
    return _sample_points(terrain, origin, level, shape)


def sample_clipbox(terrain, origin: jax.Array, level: jax.Array, *, size: int) -> ClipBox:
    """Samples a full Clip-Box of ``size^3`` voxels (3.4.3).

    Args:
        terrain: terrain pytree.
        origin: (3,) int32, a multiple of 2^(level+1) (see :func:`clipbox_origin`).
        level: the level: a Python int (static under ``jit``; lets the binned CSG
            share bins between voxels, see :meth:`CSGTerrain.sample_grid`) or a
            () int32 (may be traced).
        size: static N.
    """
    vox = sample_terrain(terrain, origin, level=level, shape=(size, size, size))
    level = jnp.asarray(level, _I32)
    return ClipBox(origin=jnp.asarray(origin, _I32), voxels=vox, level=level, size=size)


def slab_thickness(delta) -> tuple[int, int, int]:
    """Static slab thickness per axis for a box shift of ``delta`` voxels (host side).

    The next power of two >= |delta_d| (0 when the axis does not move), so only a
    handful of shapes are ever compiled.
    """
    out = []
    for d in np.abs(np.asarray(delta, np.int64)):
        out.append(0 if d == 0 else 1 << int(np.ceil(np.log2(d))))
    return tuple(out)


def shift_clipbox(
    terrain,
    box: ClipBox,
    new_origin: jax.Array,
    *,
    slabs: tuple[int, int, int],
    level: int | None = None,
):
    """Differential update (3.4.6, Fig. 3.11): reuse the overlap, sample only new slabs.

    Args:
        terrain: terrain pytree.
        box: the current box.
        new_origin: (3,) int32, a multiple of 2^(level+1).
        slabs: static per-axis slab thickness >= |shift| in voxels (see
            :func:`slab_thickness`); only ``sum_d slabs_d N^2`` points are sampled.
        level: optional static copy of ``box.level`` for the sampling fast paths
            (see :func:`sample_clipbox`); it must equal ``box.level``.
    Returns:
        The moved :class:`ClipBox`; equals :func:`sample_clipbox` at ``new_origin``.
    """
    n, lvl = box.size, box.level
    new_origin = jnp.asarray(new_origin, _I32)
    delta = jnp.right_shift(new_origin - box.origin, lvl)  # voxels
    vox = jnp.roll(box.voxels, -delta, axis=(0, 1, 2))
    for axis, t in enumerate(slabs):
        if t == 0:
            continue
        # The slab is t >= |delta| voxels thick: it covers the exposed voxels and
        # re-samples a few reused ones, which the terrain gives back unchanged, so
        # it is written over the box as a whole (in place, no mask over N^3).
        start = jnp.where(delta[axis] > 0, n - t, 0)
        s_origin = new_origin.at[axis].add(start << lvl)
        shape = [n, n, n]
        shape[axis] = t
        slab = sample_terrain(
            terrain, s_origin, level=lvl if level is None else level, shape=tuple(shape)
        )
        vox = jax.lax.dynamic_update_slice(
            vox, slab, tuple(jnp.where(a == axis, start, 0) for a in range(3))
        )
    return ClipBox(origin=new_origin, voxels=vox, level=lvl, size=n)


def reused_fraction(old_origin, new_origin, level: int, size: int) -> float:
    """Fraction of the moved box's voxels copied from the old box (3.4.6), host side."""
    d = np.abs(np.asarray(new_origin, np.int64) - np.asarray(old_origin, np.int64)) >> level
    return float(np.prod(np.clip(size - d, 0, size)) / float(size) ** 3)


def pattern_filter(voxels: jax.Array) -> jax.Array:
    """The 2x2 pattern filter (3.4.7, Fig. 3.14) on a (N, N, N) bool volume.

    A 2x2 window in any axis-aligned plane holding only a diagonal pair (solid
    voxels touching at an edge only) makes smoothing pull the surface into a
    pinch; the pattern is replaced by the filled window, so the air corners of
    every such window become solid.
    """
    v = voxels
    fill = jnp.zeros_like(v)
    for a, b in ((0, 1), (0, 2), (1, 2)):

        def win(da, db, a=a, b=b):
            s = [slice(None)] * 3
            s[a] = slice(da, v.shape[a] - 1 + da)
            s[b] = slice(db, v.shape[b] - 1 + db)
            return tuple(s)

        p00, p10, p01, p11 = v[win(0, 0)], v[win(1, 0)], v[win(0, 1)], v[win(1, 1)]
        diag1 = p00 & p11 & ~p10 & ~p01
        diag2 = p10 & p01 & ~p00 & ~p11
        hit = diag1 | diag2
        for da, db in ((0, 0), (1, 0), (0, 1), (1, 1)):
            pad = [(0, 0)] * 3
            pad[a] = (da, 1 - da)
            pad[b] = (db, 1 - db)
            fill = fill | jnp.pad(hit, pad)
    return v | fill


# --------------------------------------------------------------------------------------
# Voxels -> polygons, seams, post-processing (3.4.4, 3.4.5, 3.4.7)
# --------------------------------------------------------------------------------------


# Bit sets in a "planar" layout: flat index i is bit i // W of word i % W (W words).
# Packing is then 32 contiguous, vectorised ORs instead of a reduction over strided
# rows (5-10x faster on XLA:CPU).  Enumeration order (select / rank) is word-major,
# so ids are deterministic but not in flat-index order -- nothing relies on that.


def _pack_bits(mask: jax.Array) -> jax.Array:
    """(M,) bool -> (W,) uint32 words, W = ceil(M / 32), bit k of word w = mask[k W + w]."""
    m = mask.shape[0]
    w = -(-m // 32)
    planes = jnp.pad(mask, (0, 32 * w - m)).reshape(32, w)
    words = jnp.where(planes[0], jnp.uint32(1), jnp.uint32(0))
    for k in range(1, 32):  # where, not convert: XLA would materialise 32 converted planes
        words = words | jnp.where(planes[k], jnp.uint32(1 << k), jnp.uint32(0))
    return words


def _rank_words(words: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Per-word set-bit count and the exclusive prefix count (a rank/select directory).

    Prefix sums over N^3 / 32 words instead of N^3 bools: XLA's CPU cumsum is the
    bottleneck of a naive ``flatnonzero`` compaction.
    """
    cnt = jax.lax.population_count(words).astype(_I32)
    return cnt, jnp.cumsum(cnt) - cnt


def _select(words, cnt, start, q: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(word, bit) of the ``q``-th set bit (q ascending); garbage past the total.

    The flat index is ``bit * W + word`` for a single packed mask.
    """
    w = jnp.searchsorted(start + cnt, q, side="right").astype(_I32)
    w = jnp.minimum(w, words.shape[0] - 1)
    r = q - start[w]
    word = words[w]
    pos = jnp.zeros_like(q)
    for width in (16, 8, 4, 2, 1):
        low = jnp.right_shift(word, pos.astype(jnp.uint32)) & jnp.uint32((1 << width) - 1)
        c = jax.lax.population_count(low).astype(_I32)
        up = r >= c
        pos = pos + jnp.where(up, width, 0)
        r = r - jnp.where(up, c, 0)
    return w, pos


def _rank(words, start, idx: jax.Array) -> jax.Array:
    """Number of set bits enumerated before flat index ``idx`` (the id of a set bit)."""
    w = idx % words.shape[0]
    b = (idx // words.shape[0]).astype(jnp.uint32)
    below = words[w] & ((jnp.uint32(1) << b) - jnp.uint32(1))
    return start[w] + jax.lax.population_count(below).astype(_I32)


def _bit(words, idx: jax.Array) -> jax.Array:
    b = (idx // words.shape[0]).astype(jnp.uint32)
    return (jnp.right_shift(words[idx % words.shape[0]], b) & jnp.uint32(1)) == 1


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ClipBoxMesh:
    """Indexed triangle mesh of one Clip-Box, padded to static capacities (3.4.2, Fig. 3.4).

    Each quad of 3.4.4 is two triangles ``2q`` and ``2q + 1`` (triangles that the
    seam snap made degenerate are invalid).  Positions are float32 world units
    relative to ``origin``, so they stay small wherever the box is.

    Attributes:
        vertices: (V, 3) float32 positions relative to ``origin``.
        normals: (V, 3) float32 unit normals (zero until :func:`mesh_normals`).
        lattice: (V, 3) int32 lattice corner of each vertex, in [0, N].
        neighbors: (V, 6) int32 vertex ids along -x, +x, -y, +y, -z, +z joined by a
            mesh edge, or -1 (the vertex-to-vertex links of Fig. 3.4).
        faces: (F, 3) int32 vertex ids, counter-clockwise seen from the air side.
        face_valid: (F,) bool.
        face_center2: (F, 3) int32 twice the quad centre in lattice units.
        vertex_words: ((N + 1)^3 / 32,) uint32 bit set of used lattice corners.
        vertex_start: same shape, int32 vertex id of each word's first set bit
            (with ``vertex_words`` the voxel-to-vertex link of Fig. 3.4).
        num_quads: () int32 quads the box really has (> F / 2 means overflow).
        num_vertices: () int32 vertices the box really has (> V means overflow).
        origin: (3,) int32 world origin of the box.
        level: () int32.
        size: static N.
    """

    vertices: jax.Array
    normals: jax.Array
    lattice: jax.Array
    neighbors: jax.Array
    faces: jax.Array
    face_valid: jax.Array
    face_center2: jax.Array
    vertex_words: jax.Array
    vertex_start: jax.Array
    num_quads: jax.Array
    num_vertices: jax.Array
    origin: jax.Array
    level: jax.Array
    size: int = _static()

    @property
    def overflow(self) -> jax.Array:
        """True when the capacities were too small (the host driver re-runs larger)."""
        return (self.num_quads * 2 > self.faces.shape[0]) | (
            self.num_vertices > self.vertices.shape[0]
        )

    def vertex_id(self, lattice: jax.Array) -> jax.Array:
        """Vertex id at integer lattice corners (..., 3), -1 where there is none."""
        m1 = self.size + 1
        ok = jnp.all((lattice >= 0) & (lattice <= self.size), axis=-1)
        c = jnp.clip(lattice, 0, self.size)
        flat = (c[..., 0] * m1 + c[..., 1]) * m1 + c[..., 2]
        vid = _rank(self.vertex_words, self.vertex_start, flat)
        used = _bit(self.vertex_words, flat)
        return jnp.where(ok & used & (vid < self.vertices.shape[0]), vid, -1)


def _seam_occupancy(voxels: jax.Array) -> jax.Array:
    """Ring of one outer voxel (two inner voxels) takes the outer lattice samples (Fig. 3.7).

    The outer box samples the terrain at the even inner indices, so copying those
    samples onto the ring makes the inner surface cross the box boundary exactly
    where the outer surface does.  The six ring slabs are written in place (each
    N^2 work) rather than blending a full up-sampled copy of the box.
    """
    n = voxels.shape[0]

    def up(c):  # (n/2, n/2) -> (n, n)
        return jnp.repeat(jnp.repeat(c, 2, axis=0), 2, axis=1)

    out = voxels
    for axis in range(3):
        for lo in (0, n - 2):  # even, so these planes are outer lattice samples
            plane = jax.lax.index_in_dim(voxels, lo, axis=axis, keepdims=False)[::2, ::2]
            slab = jnp.expand_dims(up(plane), axis).repeat(2, axis=axis)
            start = [0, 0, 0]
            start[axis] = lo
            out = jax.lax.dynamic_update_slice(out, slab, tuple(start))
    return out


def _snap(c: jax.Array, n: int) -> jax.Array:
    """Boundary lattice points between two outer lattice points -> the lower one."""
    on_b = jnp.any((c == 0) | (c == n), axis=-1, keepdims=True)
    return jnp.where(on_b, c - jnp.bitwise_and(c, 1), c)


def voxels_to_mesh(
    box: ClipBox, *, max_quads: int, max_vertices: int | None = None, seam: bool = True
) -> ClipBoxMesh:
    """Voxels -> quads between solid and air voxels with shared lattice vertices (3.4.4).

    Quads are compacted from the (3, N, N, N-1) face masks with a bit-packed
    rank/select directory, so the cost is O(N^3 / 32) prefix sums plus O(quads).

    Args:
        box: the Clip-Box.
        max_quads: static quad capacity (F = 2 max_quads triangles).
        max_vertices: static vertex capacity (default ``max_quads + 16 N``).
        seam: prepare the box to be welded into the next outer level (Fig. 3.6-3.7):
            the boundary ring copies the outer lattice samples and boundary vertices
            between two outer lattice vertices are snapped onto the lower one, which
            turns the 2x1 inner quads along the seam into a fan without T-junctions.
    Returns:
        :class:`ClipBoxMesh` (normals zero).
    """
    n = box.size
    vmax = max_quads + 16 * n if max_vertices is None else max_vertices
    occ = _seam_occupancy(box.voxels) if seam else box.voxels
    # Per axis d, a (N, N, N-1)-style face mask packed on its own, so the masks are
    # never concatenated; word w of axis d is global word d W_d + w.
    words = []
    for d in range(3):
        lo = jax.lax.slice_in_dim(occ, 0, n - 1, axis=d)
        hi = jax.lax.slice_in_dim(occ, 1, n, axis=d)
        words.append(_pack_bits((lo != hi).reshape(-1)))
    w_d = words[0].shape[0]
    words = jnp.concatenate(words)
    cnt, start = _rank_words(words)
    num_quads = jnp.sum(cnt)
    q = jnp.arange(max_quads, dtype=_I32)
    qvalid = q < num_quads
    w, pos = _select(words, cnt, start, q)
    w = jnp.where(qvalid, w, 0)
    pos = jnp.where(qvalid, pos, 0)
    axis = w // w_d
    r = pos * w_d + w % w_d  # flat index into axis d's mask
    base = jnp.zeros((max_quads, 3), _I32)
    for d in range(3):
        shape = [n, n, n]
        shape[d] = n - 1
        ijk = jnp.stack(jnp.unravel_index(r, tuple(shape)), axis=-1).astype(_I32)
        base = jnp.where((axis == d)[:, None], ijk, base)
    lo_solid = occ[base[:, 0], base[:, 1], base[:, 2]]  # the voxel below the face
    base = base + jnp.eye(3, dtype=_I32)[axis]  # the face lies on lattice plane i_d + 1
    eye = jnp.eye(3, dtype=_I32)
    e_u = eye[(axis + 1) % 3]
    e_v = eye[(axis + 2) % 3]
    # e_u x e_v = e_axis: counter-clockwise seen from +axis; flip when the air is below.
    c1 = jnp.where(lo_solid[:, None], base + e_u, base + e_v)
    c3 = jnp.where(lo_solid[:, None], base + e_v, base + e_u)
    corners = jnp.stack([base, c1, base + e_u + e_v, c3], axis=1)  # (Q, 4, 3)
    center2 = 2 * base + e_u + e_v
    m1 = n + 1
    big = 3 * m1**3  # out-of-range index: scatters with mode="drop" skip it

    def flat_of(c):
        return (c[..., 0] * m1 + c[..., 1]) * m1 + c[..., 2]

    snapped = _snap(corners, n) if seam else corners
    cflat = flat_of(snapped)  # (Q, 4)
    cflat_used = jnp.where(qvalid[:, None], cflat, big)
    used = jnp.zeros((m1**3,), bool).at[cflat_used.reshape(-1)].set(True, mode="drop")
    vwords = _pack_bits(used)
    vcnt, vstart = _rank_words(vwords)
    num_vertices = jnp.sum(vcnt)
    vq = jnp.arange(vmax, dtype=_I32)
    vvalid = vq < num_vertices
    vw, vpos = _select(vwords, vcnt, vstart, vq)
    vflat = jnp.where(vvalid, vpos * vwords.shape[0] + vw, 0)
    lattice = jnp.stack(jnp.unravel_index(vflat, (m1, m1, m1)), axis=-1).astype(_I32)
    lattice = jnp.where(vvalid[:, None], lattice, 0)
    ids = _rank(vwords, vstart, cflat)  # (Q, 4)
    tri = jnp.stack([ids[:, [0, 1, 2]], ids[:, [0, 2, 3]]], axis=1).reshape(-1, 3)
    tvalid = jnp.repeat(qvalid, 2)
    tvalid &= (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    tvalid &= jnp.all(tri < vmax, axis=-1)
    tri = jnp.where(tvalid[:, None], tri, 0)
    # Vertex-to-vertex links (Fig. 3.4) straight from the quads' unit lattice edges:
    # corner k links to corner k + 1 and back.  A corner moved by the seam snap has
    # no links of its own (its vertex is the snap target's), and a link to a moved
    # corner goes to its target.  Every writer of a (vertex, direction) slot writes
    # the same id, so the scatter is deterministic.
    # The quad's edges k -> k + 1 run along +a, +b, -a, -b, where (a, b) is
    # (e_u, e_v) when the solid is below and (e_v, e_u) otherwise (see c1, c3).
    d_a = jnp.where(lo_solid, (axis + 1) % 3, (axis + 2) % 3)
    d_b = 3 - axis - d_a
    d = jnp.stack([d_a, d_b, d_a, d_b], axis=1)  # (Q, 4)
    up = jnp.asarray([1, 1, 0, 0], _I32)
    own = jnp.all(snapped == corners, axis=-1) & qvalid[:, None]
    ids_next = jnp.roll(ids, -1, axis=1)
    own_next = jnp.roll(own, -1, axis=1)
    link = (ids != ids_next) & (ids < vmax) & (ids_next < vmax)
    # Flat (vertex, direction) slots; vertex id vmax lands past the end and is dropped.
    src = jnp.concatenate(
        [
            jnp.where(own & link, ids, vmax) * 6 + 2 * d + up,
            jnp.where(own_next & link, ids_next, vmax) * 6 + 2 * d + 1 - up,
        ]
    )
    val = jnp.concatenate([ids_next, ids])
    nbrs = (
        jnp.full((vmax * 6,), -1, _I32)
        .at[src.reshape(-1)]
        .set(val.reshape(-1), mode="drop")
        .reshape(vmax, 6)
    )
    scale = jnp.left_shift(1, box.level).astype(jnp.float32)
    return ClipBoxMesh(
        vertices=lattice.astype(jnp.float32) * scale,
        normals=jnp.zeros((vmax, 3), jnp.float32),
        lattice=lattice,
        neighbors=nbrs,
        faces=tri,
        face_valid=tvalid,
        face_center2=jnp.repeat(center2, 2, axis=0),
        vertex_words=vwords,
        vertex_start=vstart,
        num_quads=num_quads,
        num_vertices=num_vertices,
        origin=box.origin,
        level=box.level,
        size=n,
    )


def smooth_mesh(mesh: ClipBoxMesh, *, iterations: int = 4, weight: float = 0.5) -> ClipBoxMesh:
    """Smoothing by vertex averaging over the vertex-to-vertex links (3.4.7, Fig. 3.9).

    ``p <- p + weight (mean of linked neighbours - p)``, ``iterations`` times.  The
    averaging works in world units, so the amount of smoothing grows linearly with
    the level's voxel size, as in 3.5.3.

    Args:
        mesh: the mesh.
        iterations: static number of averaging steps.
        weight: step in [0, 1].
    """
    nb = mesh.neighbors
    v = nb.shape[0]
    has = nb >= 0
    # Missing links read an appended zero row: six plain gathers and adds, no
    # masked (V, 6, 3) reduction (8x faster on XLA:CPU).
    idx = jnp.where(has, nb, v)
    deg = jnp.sum(has, axis=-1, keepdims=True).astype(jnp.float32)
    ok = deg > 0
    step_w = weight * jnp.where(ok, 1.0 / jnp.where(ok, deg, 1.0), 0.0)

    def step(p, _):
        pe = jnp.concatenate([p, jnp.zeros((1, 3), p.dtype)])
        total = pe[idx[:, 0]]
        for k in range(1, 6):
            total = total + pe[idx[:, k]]
        # p + weight (mean - p); a vertex without links keeps p (step_w = 0).
        return p + step_w * (total - deg * p), None

    p, _ = jax.lax.scan(step, mesh.vertices, None, length=iterations)
    return dataclasses.replace(mesh, vertices=p)


def mesh_normals(mesh: ClipBoxMesh) -> ClipBoxMesh:
    """Area-weighted vertex normals ("surface normals" of Table 3.1)."""
    p = mesh.vertices
    a, b, c = p[mesh.faces[:, 0]], p[mesh.faces[:, 1]], p[mesh.faces[:, 2]]
    fn = jnp.cross(b - a, c - a) * mesh.face_valid[:, None]
    v = p.shape[0]
    acc = sum(jax.ops.segment_sum(fn, mesh.faces[:, k], num_segments=v) for k in range(3))
    n2 = jnp.sum(acc * acc, axis=-1, keepdims=True)
    ok = n2 > 1e-20
    nrm = jnp.where(ok, acc * jax.lax.rsqrt(jnp.where(ok, n2, 1.0)), 0.0)
    return dataclasses.replace(mesh, normals=nrm)


def weld_seam(inner: ClipBoxMesh, outer: ClipBoxMesh) -> ClipBoxMesh:
    """Welds an inner mesh onto the next outer level (3.4.5, Fig. 3.7).

    Every inner vertex on the inner box boundary sits on the outer lattice (see
    :func:`voxels_to_mesh` with ``seam=True``); it takes the outer mesh's (smoothed)
    position and normal there, so both meshes share the seam exactly.

    Args:
        inner: level-l mesh built with ``seam=True``.
        outer: level-(l+1) mesh whose box contains the inner box.
    """
    n_in, n_out = inner.size, outer.size
    on_b = jnp.any((inner.lattice == 0) | (inner.lattice == n_in), axis=-1)
    on_b &= jnp.arange(inner.lattice.shape[0]) < inner.num_vertices
    off = jnp.right_shift(inner.origin - outer.origin, outer.level)  # outer voxels
    q = off + jnp.right_shift(inner.lattice, 1)
    inside = jnp.all((q >= 0) & (q <= n_out), axis=-1)
    vid = outer.vertex_id(q)
    ok = on_b & inside & (vid >= 0) & (vid < outer.vertices.shape[0])
    vid = jnp.where(ok, vid, 0)
    shift = (outer.origin - inner.origin).astype(jnp.float32)
    pos = jnp.where(ok[:, None], outer.vertices[vid] + shift, inner.vertices)
    nrm = jnp.where(ok[:, None], outer.normals[vid], inner.normals)
    return dataclasses.replace(inner, vertices=pos, normals=nrm)


def visible_faces(mesh: ClipBoxMesh, inner_origin=None, inner_extent=None) -> jax.Array:
    """Faces to draw: valid and not covered by the next inner box (3.4.5).

    Args:
        mesh: level-l mesh.
        inner_origin: (3,) int32 world origin of the level-(l-1) box, or None.
        inner_extent: () int32 world edge of that box (``N 2^(l-1)``).
    Returns:
        (F,) bool.
    """
    if inner_origin is None:
        return mesh.face_valid
    lo2 = 2 * jnp.right_shift(jnp.asarray(inner_origin, _I32) - mesh.origin, mesh.level)
    hi2 = lo2 + 2 * jnp.right_shift(jnp.asarray(inner_extent, _I32), mesh.level)
    c = mesh.face_center2
    covered = jnp.all((c > lo2) & (c < hi2), axis=-1)
    return mesh.face_valid & ~covered


class SubdividedMesh(NamedTuple):
    """Triangle mesh after subdivision (3.4.7, Fig. 3.12); midpoints are per triangle edge."""

    vertices: jax.Array  # (V + 3F, 3) float32, relative to the box origin
    normals: jax.Array  # (V + 3F, 3) float32
    faces: jax.Array  # (4F, 3) int32
    face_valid: jax.Array  # (4F,) bool


def _hash_uniform(p2: jax.Array, seed: jax.Array) -> jax.Array:
    """Deterministic uniform [-1, 1) per integer point (uint32 mixing, wraps on purpose)."""
    h = p2.astype(jnp.uint32) * jnp.asarray([0x8DA6B343, 0xD8163841, 0xCB1AB31F], jnp.uint32)
    x = h[..., 0] ^ h[..., 1] ^ h[..., 2] ^ seed
    for mul in (0x7FEB352D, 0x846CA68B):
        x = (x ^ (x >> 16)) * jnp.uint32(mul)
    x = x ^ (x >> 16)
    return (x >> 8).astype(jnp.float32) * (2.0 / (1 << 24)) - 1.0


def subdivide_mesh(
    mesh: ClipBoxMesh, *, key: jax.Array, amplitude: float = 0.25, visible=None
) -> SubdividedMesh:
    """Triangle subdivision with random midpoint displacement ("fractal details", 3.4.7).

    Each triangle becomes four through its edge midpoints; a midpoint moves along
    the mean of its end normals by ``amplitude * 2^level * u``, ``u`` in [-1, 1)
    hashed from the midpoint's exact integer world position and ``key``.  Both
    triangles of an edge compute the same midpoint, so no cracks open; midpoints
    of edges on the box boundary are not displaced so the seam to the outer level
    stays on the outer edge (Fig. 3.13).

    Args:
        mesh: a mesh with normals (after :func:`mesh_normals`).
        key: PRNG key for the displacement field.
        amplitude: displacement in voxels of this level.
        visible: optional (F,) mask (e.g. from :func:`visible_faces`).
    Returns:
        :class:`SubdividedMesh`.
    """
    f = mesh.faces
    nf = f.shape[0]
    nv = mesh.vertices.shape[0]
    valid = mesh.face_valid if visible is None else visible
    seed = jax.random.bits(key, (), jnp.uint32)
    a_idx = f
    b_idx = jnp.roll(f, -1, axis=1)  # edges (0,1), (1,2), (2,0)
    pa, pb = mesh.vertices[a_idx], mesh.vertices[b_idx]
    mid = 0.5 * (pa + pb)  # symmetric in a, b: both triangles of an edge agree
    nrm = mesh.normals[a_idx] + mesh.normals[b_idx]
    n2 = jnp.sum(nrm * nrm, -1, keepdims=True)
    ok = n2 > 1e-12
    nrm = jnp.where(ok, nrm * jax.lax.rsqrt(jnp.where(ok, n2, 1.0)), 0.0)
    la, lb = mesh.lattice[a_idx], mesh.lattice[b_idx]
    s = jnp.left_shift(1, mesh.level)
    p2 = 2 * mesh.origin + (la + lb) * s  # doubled world coordinate of the midpoint
    n = mesh.size
    rim = jnp.any(((la == 0) & (lb == 0)) | ((la == n) & (lb == n)), axis=-1, keepdims=True)
    u = _hash_uniform(p2, seed)[..., None]
    mid = mid + jnp.where(rim, 0.0, amplitude * s.astype(jnp.float32) * u) * nrm
    m = nv + 3 * jnp.arange(nf, dtype=_I32)[:, None] + jnp.arange(3, dtype=_I32)  # (F, 3)
    faces = jnp.stack(
        [
            jnp.stack([f[:, 0], m[:, 0], m[:, 2]], -1),
            jnp.stack([m[:, 0], f[:, 1], m[:, 1]], -1),
            jnp.stack([m[:, 2], m[:, 1], f[:, 2]], -1),
            jnp.stack([m[:, 0], m[:, 1], m[:, 2]], -1),
        ],
        axis=1,
    ).reshape(-1, 3)
    return SubdividedMesh(
        vertices=jnp.concatenate([mesh.vertices, mid.reshape(-1, 3)]),
        normals=jnp.concatenate([mesh.normals, nrm.reshape(-1, 3)]),
        faces=jnp.where(jnp.repeat(valid, 4)[:, None], faces, 0),
        face_valid=jnp.repeat(valid, 4),
    )


# --------------------------------------------------------------------------------------
# Nested Clip-Boxes and the host-side update driver (3.3.1, 3.4.5, 3.4.6)
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class NestedClipBoxes:
    """State of ``L`` nested Clip-Boxes, level 0 innermost (3.4.5, Fig. 3.2).

    Attributes:
        boxes: L :class:`ClipBox` (volume data, cached for differential updates).
        meshes: L welded, smoothed :class:`ClipBoxMesh` ready to draw.
    """

    boxes: tuple
    meshes: tuple

    @property
    def levels(self) -> int:
        return len(self.boxes)

    def origins(self) -> np.ndarray:
        """(L, 3) int64 box origins (host)."""
        return np.stack([np.asarray(b.origin, np.int64) for b in self.boxes])


def nested_origins(viewer, *, levels: int, size: int) -> np.ndarray:
    """(L, 3) origins of boxes centred on ``viewer`` (host side, Fig. 3.10)."""
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 1:
        raise ValueError(f"levels must be an int >= 1, got {levels!r}")
    return np.stack([clipbox_origin(viewer, lvl, size) for lvl in range(levels)])


def _nested_ok(inner_origin, outer_origin, level: int, size: int) -> bool:
    """Inner box inside the outer one with a margin of one outer voxel."""
    s_out = 2 << level
    lo = np.asarray(inner_origin) - np.asarray(outer_origin)
    hi = lo + size * (1 << level)
    return bool(np.all(lo >= s_out) and np.all(hi <= size * s_out - s_out))


def _block(x):
    return jax.block_until_ready(x)


class ClipBoxPipeline:
    """Builds and moves nested Clip-Boxes around a viewer (host driver, Fig. 3.1 thread 1).

    It holds jitted versions of the pure steps (``sample_fn``, ``shift_fn``,
    ``extract_fn``, ``smooth_fn``, ``normals_fn``, ``weld_fn``; this object plays
    the caller that jits).  Sampling is compiled per level (the level is static
    there so the binned CSG can share bins between voxels); the meshing steps
    are compiled once for every level because the box's level is a traced leaf.

    Args:
        terrain: a terrain (validated with :func:`check_terrain`).
        size: N, voxels per box edge, a multiple of 8.
        levels: L >= 1 nested boxes.
        max_quads: initial quad capacity per box (default ``2 N^2``); a level's
            capacity (``capacity[level]``) grows to the next power of two >= twice
            the old one and the box is rebuilt whenever it has more (never truncated).
        smoothing: averaging iterations per box (3.4.7).
        smoothing_weight: averaging step.
        move_threshold: a box moves once the viewer is this many of its voxels
            away from its centre (default N / 8); inner boxes therefore follow
            the viewer more often than outer ones (3.4.6).
        pattern: apply the 2x2 pattern filter before meshing (Fig. 3.14).
        subdivide: innermost levels drawn with subdivision and random midpoint
            displacement (3.4.7); 0 disables it.
        detail_amplitude: midpoint displacement in voxels.
        key: PRNG key of the displacement field (required when ``subdivide > 0``).
    """

    def __init__(
        self,
        terrain,
        *,
        size: int = 128,
        levels: int = 7,
        max_quads: int | None = None,
        smoothing: int = 4,
        smoothing_weight: float = 0.5,
        move_threshold: int | None = None,
        pattern: bool = False,
        subdivide: int = 0,
        detail_amplitude: float = 0.25,
        key: jax.Array | None = None,
    ):
        self.terrain = check_terrain(terrain)
        if isinstance(subdivide, bool) or not isinstance(subdivide, (int, np.integer)):
            raise TypeError(f"subdivide must be an int, got {type(subdivide).__name__}")
        if subdivide < 0:
            raise ValueError(f"subdivide must be >= 0, got {subdivide}")
        if subdivide and key is None:
            raise ValueError("key is required when subdivide > 0")
        self.subdivide = int(subdivide)
        self.detail_amplitude = float(detail_amplitude)
        self.key = key
        self.size = _check_size(size)
        if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 1:
            raise ValueError(f"levels must be an int >= 1, got {levels!r}")
        self.levels = int(levels)
        self.max_quads = int(max_quads) if max_quads is not None else 2 * self.size**2
        if self.max_quads < 1:
            raise ValueError(f"max_quads must be >= 1, got {max_quads}")
        self.capacity: dict[int, int] = {}  # grown quad capacity per level
        if (
            isinstance(smoothing, bool)
            or not isinstance(smoothing, (int, np.integer))
            or smoothing < 0
        ):
            raise ValueError(f"smoothing must be an int >= 0, got {smoothing!r}")
        if not 0.0 <= smoothing_weight <= 1.0:
            raise ValueError(f"smoothing_weight must be in [0, 1], got {smoothing_weight}")
        self.smoothing = int(smoothing)
        self.smoothing_weight = float(smoothing_weight)
        t = self.size // 8 if move_threshold is None else int(move_threshold)
        if not 1 <= t <= self.size // 2 - 6:
            raise ValueError(f"move_threshold must be in [1, N/2 - 6], got {t}")
        self.move_threshold = t
        self.pattern = bool(pattern)
        self.sample_fn = jax.jit(sample_clipbox, static_argnames=("size", "level"))
        self.shift_fn = jax.jit(shift_clipbox, static_argnames=("slabs", "level"))
        self.filter_fn = jax.jit(lambda b: dataclasses.replace(b, voxels=pattern_filter(b.voxels)))
        self.extract_fn = jax.jit(voxels_to_mesh, static_argnames=("max_quads", "seam"))
        self.smooth_fn = jax.jit(smooth_mesh, static_argnames=("iterations",))
        self.normals_fn = jax.jit(mesh_normals)
        self.weld_fn = jax.jit(weld_seam)
        self.subdivide_fn = jax.jit(subdivide_mesh)

    def views(self, state: NestedClipBoxes) -> list[dict[str, np.ndarray]]:
        """:func:`level_views` with this pipeline's subdivision settings."""
        return level_views(
            state,
            subdivide=self.subdivide,
            key=self.key,
            amplitude=self.detail_amplitude,
            subdivide_fn=self.subdivide_fn,
        )

    def _check_viewer(self, viewer) -> np.ndarray:
        v = np.asarray(viewer)
        if v.shape != (3,) or not np.issubdtype(v.dtype, np.integer):
            raise ValueError(f"viewer must be 3 integer voxel coordinates, got {viewer!r}")
        reach = self.size * (1 << self.levels)
        if np.any(np.abs(v.astype(np.int64)) > 2**31 - 1 - 2 * reach):
            raise ValueError(f"viewer {viewer!r} is outside the int32 world")
        return v.astype(np.int64)

    def build_mesh(self, box: ClipBox, *, seam: bool, timings: dict | None = None):
        """Voxels -> welded-ready mesh: polygons, smoothing, normals (3.4.4, 3.4.7)."""
        t0 = time.perf_counter()
        if self.pattern:
            box = self.filter_fn(box)
        # Capacity per level (coarse levels carry more quads); grown to a power of two
        # so the levels share a few compiled shapes.
        lvl = int(box.level)
        while True:
            cap = self.capacity.get(lvl, self.max_quads)
            mesh = self.extract_fn(box, max_quads=cap, seam=seam)
            if not bool(mesh.overflow):
                break
            self.capacity[lvl] = 1 << int(max(2 * cap, int(mesh.num_quads) + 1) - 1).bit_length()
        t1 = time.perf_counter()
        mesh = _block(self.smooth_fn(mesh, iterations=self.smoothing, weight=self.smoothing_weight))
        t2 = time.perf_counter()
        mesh = _block(self.normals_fn(mesh))
        t3 = time.perf_counter()
        if timings is not None:
            timings["polygons_ms"] = 1e3 * (t1 - t0)
            timings["smoothing_ms"] = 1e3 * (t2 - t1)
            timings["normals_ms"] = 1e3 * (t3 - t2)
        return mesh

    def _weld_all(self, meshes: list, changed) -> list:
        # Welding only rewrites an inner mesh's boundary vertices, which lie strictly
        # inside the outer box, so welded meshes can be re-welded in any order.
        out = list(meshes)
        for lvl in range(self.levels - 1):
            if lvl in changed or lvl + 1 in changed:
                out[lvl] = self.weld_fn(out[lvl], out[lvl + 1])
        return out

    def init(self, viewer) -> NestedClipBoxes:
        """Samples and meshes every level around ``viewer``."""
        v = self._check_viewer(viewer)
        origins = nested_origins(v, levels=self.levels, size=self.size)
        boxes = [
            self.sample_fn(self.terrain, jnp.asarray(o, _I32), lvl, size=self.size)
            for lvl, o in enumerate(origins)
        ]
        raw = [self.build_mesh(b, seam=lvl < self.levels - 1) for lvl, b in enumerate(boxes)]
        return NestedClipBoxes(tuple(boxes), tuple(self._weld_all(raw, range(self.levels))))

    def plan(self, state: NestedClipBoxes, viewer) -> dict[int, np.ndarray]:
        """Which levels move, and where (host side, 3.4.6, Fig. 3.10)."""
        v = self._check_viewer(viewer)
        cur = state.origins()
        new = cur.copy()
        moves = {}
        for lvl in range(self.levels):
            want = clipbox_origin(v, lvl, self.size)
            off = np.abs(want - cur[lvl]) >> lvl
            nest_bad = lvl > 0 and not _nested_ok(new[lvl - 1], cur[lvl], lvl - 1, self.size)
            if np.max(off) >= self.move_threshold or nest_bad:
                new[lvl] = want
                moves[lvl] = want
        for lvl in range(self.levels - 1):
            if not _nested_ok(new[lvl], new[lvl + 1], lvl, self.size):
                raise RuntimeError(f"nesting broken between levels {lvl} and {lvl + 1}")
        return moves

    def update(self, state: NestedClipBoxes, viewer, *, timings: bool = False):
        """Moves the boxes that need it, with differential sampling (3.4.6).

        Returns:
            ``(state, stats)``; ``stats`` lists per moved level the reused fraction,
            the fraction of voxels sampled and (with ``timings``) the ms per stage.
        """
        moves = self.plan(state, viewer)
        if not moves:
            return state, {}
        boxes = list(state.boxes)
        meshes = list(state.meshes)
        stats = {}
        n = self.size
        for lvl, want in sorted(moves.items()):
            st: dict[str, float] = {}
            t0 = time.perf_counter()
            old = np.asarray(boxes[lvl].origin, np.int64)
            delta = (want - old) >> lvl
            if np.max(np.abs(delta)) <= n // 4:
                slabs = slab_thickness(delta)
                box = self.shift_fn(
                    self.terrain, boxes[lvl], jnp.asarray(want, _I32), slabs=slabs, level=lvl
                )
                st["reused"] = reused_fraction(old, want, lvl, n)
                st["sampled"] = sum(slabs) / n
            else:
                box = self.sample_fn(self.terrain, jnp.asarray(want, _I32), lvl, size=n)
                st["reused"], st["sampled"] = 0.0, 1.0
            boxes[lvl] = _block(box)
            st["generation_ms"] = 1e3 * (time.perf_counter() - t0)
            meshes[lvl] = self.build_mesh(box, seam=lvl < self.levels - 1, timings=st)
            stats[lvl] = st
        t0 = time.perf_counter()
        meshes = _block(self._weld_all(meshes, set(moves)))
        for st in stats.values():
            st["welding_ms"] = 1e3 * (time.perf_counter() - t0) / len(stats)
        return NestedClipBoxes(tuple(boxes), tuple(meshes)), stats


# --------------------------------------------------------------------------------------
# Concurrency: geometry thread + double buffer + sync flag (3.3.1, Fig. 3.1, 3.5.4)
# --------------------------------------------------------------------------------------


def level_views(
    state: NestedClipBoxes,
    *,
    subdivide: int = 0,
    key: jax.Array | None = None,
    amplitude: float = 0.25,
    subdivide_fn=None,
) -> list[dict[str, np.ndarray]]:
    """Host arrays to draw each level: the part not covered by the next inner box (3.4.5).

    Args:
        state: the nested boxes.
        subdivide: the innermost ``subdivide`` levels get :func:`subdivide_mesh`
            with random midpoint displacement (3.4.7, Fig. 3.13).
        key: PRNG key for the displacement (required when ``subdivide > 0``).
        amplitude: displacement in voxels.
        subdivide_fn: a jitted :func:`subdivide_mesh` (default: the plain function).
    Returns:
        per level ``dict(vertices, normals, faces, visible, origin)``.
    """
    if subdivide and key is None:
        raise ValueError("key is required when subdivide > 0")
    sub = subdivide_fn if subdivide_fn is not None else subdivide_mesh
    out = []
    for lvl, m in enumerate(state.meshes):
        if lvl > 0:
            inner = state.boxes[lvl - 1]
            vis = visible_faces(m, inner.origin, inner.size << (lvl - 1))
        else:
            vis = m.face_valid
        if lvl < subdivide:
            sm = sub(m, key=jax.random.fold_in(key, lvl), amplitude=amplitude, visible=vis)
            verts, nrms, faces, vis = sm.vertices, sm.normals, sm.faces, sm.face_valid
        else:
            verts, nrms, faces = m.vertices, m.normals, m.faces
        out.append(
            dict(
                vertices=np.asarray(verts),
                normals=np.asarray(nrms),
                faces=np.asarray(faces),
                visible=np.asarray(vis),
                origin=np.asarray(m.origin, np.int64),
            )
        )
    return out


class GeometryWorker:
    """Geometry thread that rebuilds Clip-Boxes while the renderer draws (Fig. 3.1).

    The worker owns the back buffer and the renderer the front buffer.  When a
    rebuilt set of levels is completely written to the back buffer, the worker
    raises the sync flag and waits; the renderer's :meth:`acquire` swaps the two
    buffers and clears the flag at the start of a frame.  The renderer therefore
    only ever sees complete, mutually consistent meshes, and the worker never
    writes a buffer that is being drawn.

    A buffer is ``dict(stamp=(2,) int64 [generation at start, at end],
    levels=[per level dict(vertices, normals, faces, visible, origin, checksum)])``.

    Args:
        pipeline: the :class:`ClipBoxPipeline`.
        viewer: initial integer viewer position.
    """

    def __init__(self, pipeline: ClipBoxPipeline, viewer):
        self.pipeline = pipeline
        self.state = pipeline.init(viewer)
        self._viewer = np.asarray(viewer, np.int64)
        self._buffers = [self._new_buffer(), self._new_buffer()]
        self._write(self._buffers[0], self.state, 0)
        self._front = 0
        self._sync = False
        self._cv = threading.Condition()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self.generation = 0
        self.swaps = 0
        self.stats: list[dict] = []

    @staticmethod
    def _new_buffer() -> dict:
        return dict(stamp=np.full(2, -1, np.int64), levels=[])

    def _write(self, buf: dict, state: NestedClipBoxes, gen: int) -> None:
        buf["stamp"][0] = gen  # written first ...
        views = self.pipeline.views(state)
        if len(buf["levels"]) != len(views):
            buf["levels"] = [dict() for _ in views]
        for dst, src in zip(buf["levels"], views):
            for k, v in src.items():
                if k in dst and dst[k].shape == v.shape and dst[k].dtype == v.dtype:
                    np.copyto(dst[k], v)  # in place: tearing would be visible
                else:
                    dst[k] = v.copy()
            dst["checksum"] = float(np.sum(src["vertices"], dtype=np.float64))
            dst["generation"] = gen
        buf["stamp"][1] = gen  # ... and last

    def set_viewer(self, viewer) -> None:
        """Called by the renderer: where the geometry should follow."""
        self._viewer = self.pipeline._check_viewer(viewer)

    def start(self) -> GeometryWorker:
        self._thread = threading.Thread(target=self._run, name="clipbox-geometry", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        with self._cv:
            self._cv.notify_all()
        if self._thread is not None:
            self._thread.join()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                state, stats = self.pipeline.update(self.state, self._viewer)
                if not stats:
                    time.sleep(0.001)
                    continue
                self.state = state
                gen = self.generation + 1
                self._write(self._buffers[1 - self._front], state, gen)
                with self._cv:
                    self.generation = gen
                    self.stats.append(stats)
                    self._sync = True
                    while self._sync and not self._stop.is_set():
                        self._cv.wait(0.05)
        except BaseException as err:  # surfaced to the renderer in acquire()
            self._error = err

    def acquire(self) -> dict:
        """Renderer side, once per frame: swap in the newest complete buffer if flagged."""
        if self._error is not None:
            raise RuntimeError("geometry worker failed") from self._error
        with self._cv:
            if self._sync:
                self._front = 1 - self._front
                self._sync = False
                self.swaps += 1
                self._cv.notify_all()
            return self._buffers[self._front]


# --------------------------------------------------------------------------------------
# Rendering and export
# --------------------------------------------------------------------------------------


def level_arrays(levels: Sequence[dict], anchor) -> tuple[np.ndarray, ...]:
    """Concatenates buffer levels relative to the integer ``anchor`` (3.5.3).

    Only the small integer ``origin - anchor`` is turned into floats, so the result
    is equally precise at x = 0 and at x = 10^9.

    Returns:
        ``(vertices (V, 3) float32, normals (V, 3), faces (F, 3) int32 with hidden
        faces removed, level (V,) int32)``.
    """
    anchor = np.asarray(anchor, np.int64)
    vs, ns, fs, ls = [], [], [], []
    off = 0
    for lvl, lv in enumerate(levels):
        shift = (lv["origin"] - anchor).astype(np.float32)
        vs.append(lv["vertices"] + shift)
        ns.append(lv["normals"])
        fs.append(lv["faces"][lv["visible"]] + off)
        ls.append(np.full(lv["vertices"].shape[0], lvl, np.int32))
        off += lv["vertices"].shape[0]
    return (
        np.concatenate(vs).astype(np.float32),
        np.concatenate(ns).astype(np.float32),
        np.concatenate(fs).astype(np.int32),
        np.concatenate(ls),
    )


def render_levels(
    cam,
    levels: Sequence[dict],
    anchor,
    *,
    albedo=(0.62, 0.56, 0.48),
    light_dir=(0.4, 0.8, 0.3),
    rasterize_fn=None,
):
    """Draws all levels through the shared rasterizer (Fig. 3.1 thread 2).

    Args:
        cam: :class:`jaxgfx.camera.Camera` whose position is relative to ``anchor``.
        levels: ``buffer["levels"]`` from :class:`GeometryWorker` (or
            ``level_views(state)``).
        anchor: (3,) integer world position the camera is relative to.
        albedo: surface colour.
        light_dir: direction towards the light.
        rasterize_fn: a jitted ``jaxgfx.raster.rasterize`` (default: jit it here).
    Returns:
        :class:`jaxgfx.compose.Frame` (Lambert-shaded colour, depth).
    """
    from jaxgfx.compose import Frame, lambert
    from jaxgfx.raster import rasterize

    v, n, f, _ = level_arrays(levels, anchor)
    if f.shape[0] == 0:
        f = np.zeros((1, 3), np.int32)  # one degenerate triangle draws nothing
    fn = rasterize_fn if rasterize_fn is not None else jax.jit(rasterize)
    out = fn(cam, jnp.asarray(v), jnp.asarray(f), jnp.asarray(n))
    alb = jnp.broadcast_to(jnp.asarray(albedo, jnp.float32), out.color.shape)
    color = lambert(out.color, alb, light_dir)
    hit = jnp.isfinite(out.depth)[..., None]
    return Frame(jnp.where(hit, color, 0.0), out.depth)


def mesh_to_trimesh(levels: Sequence[dict], anchor=(0, 0, 0), level: int | None = None):
    """One level (or all) as a ``trimesh.Trimesh`` for PLY/GLB export (unused vertices dropped)."""
    import trimesh

    sel = list(levels) if level is None else [levels[level]]
    if level is not None and not 0 <= level < len(levels):
        raise ValueError(f"level must be in [0, {len(levels)}), got {level}")
    v, n, f, _ = level_arrays(sel, anchor)
    mesh = trimesh.Trimesh(v, f, vertex_normals=n, process=False)
    mesh.remove_unreferenced_vertices()
    return mesh
