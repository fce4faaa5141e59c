"""The host driver that builds and moves nested Clip-Boxes (thesis 3.3.1, 3.4.5-3.4.7, Fig. 3.1).

:class:`ClipBoxPipeline` holds jitted versions of the pure steps of ``clipbox.py``,
``meshing.py`` and ``postprocess.py``, plans which levels move when the viewer moves
(3.4.6, Fig. 3.10) and rebuilds those levels with the differential update; it is the
geometry thread's work in Fig. 3.1 (run concurrently by ``worker.py``).
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_int
from jaxgfx._src.terrain.clipbox import (
    ClipBox,
    NestedClipBoxes,
    _check_size,
    _reach,
    check_levels,
    clipbox_origin,
    is_nested,
    nested_origins,
    reused_fraction,
    sample_clipbox,
    shift_clipbox,
    slab_thickness,
)
from jaxgfx._src.terrain.display import level_views
from jaxgfx._src.terrain.functions import _I32
from jaxgfx._src.terrain.meshing import voxels_to_mesh
from jaxgfx._src.terrain.postprocess import (
    blend_seam,
    mesh_normals,
    pattern_filter,
    smooth_mesh,
    subdivide_mesh,
)
from jaxgfx._src.terrain.sampling import check_terrain

__all__ = ["ClipBoxPipeline"]


def _block(x):
    return jax.block_until_ready(x)


def _snap_mesh(terrain, mesh, welded: bool = False):
    """``mesh`` with its vertices on ``terrain``'s surface (``terrain.snap_to_surface``).

    ``welded``: the seam ring (lattice <= 1 or >= N - 1, see :func:`blend_seam`) keeps
    the outer mesh's positions, so the seam stays bit-exact; the blended band inside it
    goes back onto the surface (relaxed, it stood off it as a small ledge).
    """
    p = terrain.snap_to_surface(mesh.origin, mesh.vertices)
    if welded:
        c, n = mesh.lattice, mesh.size
        ring = jnp.any((c <= 1) | (c >= n - 1), axis=-1, keepdims=True)
        p = jnp.where(ring, mesh.vertices, p)
    return dataclasses.replace(mesh, vertices=p)


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
        levels: L nested boxes, ``1 <= L <=`` :func:`~jaxgfx.terrain.max_levels` of ``size``
            (21 up to N = 256); more raise ``ValueError`` here, before any work.
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
        snap: move smoothed vertices onto the terrain's own surface when it has one
            (``terrain.snap_to_surface``, height maps); False keeps the voxel mesh.
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
        snap: bool = True,
    ):
        self.terrain = check_terrain(terrain)
        subdivide = check_int("subdivide", subdivide, low=0)
        if subdivide and key is None:
            raise ValueError("key is required when subdivide > 0")
        self.subdivide = subdivide
        self.detail_amplitude = float(detail_amplitude)
        self.key = key
        self.size = _check_size(size)
        self.levels = check_levels(levels, self.size)
        self.max_quads = int(max_quads) if max_quads is not None else 2 * self.size**2
        if self.max_quads < 1:
            raise ValueError(f"max_quads must be >= 1, got {max_quads}")
        self.capacity: dict[int, int] = {}  # grown quad capacity per level
        smoothing = check_int("smoothing", smoothing, low=0)
        if not 0.0 <= smoothing_weight <= 1.0:
            raise ValueError(f"smoothing_weight must be in [0, 1], got {smoothing_weight}")
        self.smoothing = smoothing
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
        self.weld_fn = jax.jit(blend_seam)
        self.subdivide_fn = jax.jit(subdivide_mesh)
        self.snap = bool(snap)
        self.snap_fn = jax.jit(_snap_mesh, static_argnames=("welded",))

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
        limit = 2**31 - 1 - _reach(self.size, self.levels)
        if np.any(np.abs(v.astype(np.int64)) > limit):
            raise ValueError(
                f"viewer {viewer!r} is outside the int32 world: with {self.levels} levels of "
                f"size {self.size} its coordinates must be within +-{limit}"
            )
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
        mesh = self.smooth_fn(mesh, iterations=self.smoothing, weight=self.smoothing_weight)
        if self.snap and hasattr(self.terrain, "snap_to_surface"):
            mesh = self.snap_fn(self.terrain, mesh)
        mesh = _block(mesh)
        t2 = time.perf_counter()
        mesh = _block(self.normals_fn(mesh))
        t3 = time.perf_counter()
        if timings is not None:
            timings["polygons_ms"] = 1e3 * (t1 - t0)
            timings["smoothing_ms"] = 1e3 * (t2 - t1)
            timings["normals_ms"] = 1e3 * (t3 - t2)
        return mesh

    def _weld_all(self, meshes: list, changed) -> list:
        # Outermost pair first: blending moves an outer mesh's vertices up to a few
        # voxels inside its border, where the next inner box's seam may lie, so an
        # inner level is welded after (and again whenever) its outer level changed.
        out = list(meshes)
        dirty = set(changed)
        for lvl in range(self.levels - 2, -1, -1):
            if lvl in dirty or lvl + 1 in dirty:
                out[lvl] = self.weld_fn(out[lvl], out[lvl + 1])
                if self.snap and hasattr(self.terrain, "snap_to_surface"):
                    out[lvl] = self.snap_fn(self.terrain, out[lvl], welded=True)
                dirty.add(lvl)
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
            nest_bad = lvl > 0 and not is_nested(new[lvl - 1], cur[lvl], lvl - 1, self.size)
            if np.max(off) >= self.move_threshold or nest_bad:
                new[lvl] = want
                moves[lvl] = want
        for lvl in range(self.levels - 1):
            if not is_nested(new[lvl], new[lvl + 1], lvl, self.size):
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
