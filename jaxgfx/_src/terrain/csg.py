"""Random CSG terrain with spatial bins (thesis 3.4.3, Fig. 3.5; benchmark terrain of 3.5.2).

The terrain starts as ``y < ground``; integer spheres, boxes and cylinders are added
(union) or carved out (difference) in order and tiled in x and z.  A table of spatial
bins lists the primitives that can touch each bin, so a point costs O(bin occupancy),
not O(primitives); :meth:`CSGTerrain.sample_grid` shares the bins between voxels when
the voxels are smaller than a bin.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_int, static_field
from jaxgfx._src.terrain.functions import _I32, _floormod, _sample_points

__all__ = [
    "PRIMITIVE_SPHERE",
    "PRIMITIVE_BOX",
    "PRIMITIVE_CYLINDER",
    "CSGTerrain",
    "csg_terrain",
    "random_csg_terrain",
]

PRIMITIVE_SPHERE = 0
PRIMITIVE_BOX = 1
PRIMITIVE_CYLINDER = 2


# --------------------------------------------------------------------------------------
# The binned CSG terrain (one point, and a grid with shared bins)
# --------------------------------------------------------------------------------------


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
    period: int = static_field()
    bin_size: int = static_field()
    y_min: int = static_field()
    bins_y: int = static_field()
    ground: int = static_field()

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


# --------------------------------------------------------------------------------------
# Building the bins (host side)
# --------------------------------------------------------------------------------------


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
    check_int("period", period, low=1)
    check_int("bin_size", bin_size, low=1)
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
    check_int("count", count, low=0)
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
