"""Voxels -> polygons and the seams between levels (thesis 3.4.2, 3.4.4-3.4.5).

Voxels become quads on faces between solid and air voxels with shared lattice
vertices (3.4.4, Fig. 3.8), compacted with a bit-packed rank/select directory.
Seams between levels (Fig. 3.6-3.7) are closed in two steps: the outermost ring (one
outer voxel thick) of an inner box takes its occupancy from the outer lattice samples
(:func:`seam_occupancy`), and the inner boundary vertices that sit between two outer
lattice vertices are snapped onto the outer lattice; after smoothing, the inner
boundary vertices take the outer mesh's positions (:func:`weld_seam`).  The union of an
inner mesh and the outer mesh minus the inner region (:func:`visible_faces`) is then
closed along the seam.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import static_field
from jaxgfx._src.terrain.clipbox import ClipBox
from jaxgfx._src.terrain.functions import _I32

__all__ = ["ClipBoxMesh", "seam_occupancy", "voxels_to_mesh", "weld_seam", "visible_faces"]


# --------------------------------------------------------------------------------------
# Bit sets along x: rank and select (compaction for 3.4.4)
# --------------------------------------------------------------------------------------
# A box's voxels, its faces and its lattice corners are bit sets packed along x: bit b of
# word [g, y, z] is x = 32 g + b.  Neighbours along y and z are then whole words and
# along x a shift, so the face and used-corner sets come from a few word-wide bitwise
# passes (N^3 / 32 words) instead of N^3 bool passes and an (N + 1)^3 scatter.  The
# enumeration order (word-major, then bit) is deterministic; nothing relies on it.
_U32 = jnp.uint32


def _pack_x(x: jax.Array) -> jax.Array:
    """(n, A, B) bool -> (ceil(n / 32), A, B) uint32; bit b of word g is x[32 g + b]."""
    n = x.shape[0]
    g = -(-n // 32)
    x = jnp.pad(x, ((0, 32 * g - n), (0, 0), (0, 0))).reshape(g, 32, *x.shape[1:])
    words = jnp.where(x[:, 0], _U32(1), _U32(0))
    for b in range(1, 32):  # where, not convert: XLA would materialise 32 converted planes
        words = words | jnp.where(x[:, b], _U32(1 << b), _U32(0))
    return words


def _low_bits(count: int, nwords: int) -> jax.Array:
    """(nwords, 1, 1) uint32 words with the bits x < count set."""
    k = np.clip(count - 32 * np.arange(nwords), 0, 32).astype(np.uint64)
    return jnp.asarray(((np.uint64(1) << k) - np.uint64(1)).astype(np.uint32))[:, None, None]


def _next(x: jax.Array, axis: int) -> jax.Array:
    """x at index + 1 along ``axis`` (zero past the end)."""
    tail = jax.lax.slice_in_dim(x, 1, x.shape[axis], axis=axis)
    pad = [(0, 0)] * x.ndim
    pad[axis] = (0, 1)
    return jnp.pad(tail, pad)


def _next_x(x: jax.Array) -> jax.Array:
    """Bit x takes bit x + 1 of the packed axis (zero past the end)."""
    return (x >> 1) | (_next(x, 0) << 31)


def _inclusive_sum(x: jax.Array, width: int = 8) -> jax.Array:
    """Prefix sum of a 1-D int array, rows of ``width`` by doubling, then the row totals.

    XLA:CPU lowers ``jnp.cumsum`` to a reduce-window tree that costs O(128) adds per
    element; this costs O(log width) plus the (8x shorter) totals.
    """
    n = x.shape[0]
    if n <= width:
        return jnp.cumsum(x)
    rows = -(-n // width)
    y = jnp.pad(x, (0, rows * width - n)).reshape(rows, width)
    s = 1
    while s < width:
        y = y + jnp.pad(y[:, :-s], ((0, 0), (s, 0)))
        s *= 2
    total = y[:, -1]
    return (y + (_inclusive_sum(total, width) - total)[:, None]).reshape(-1)[:n]


def _directory(words: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per-word set-bit count, exclusive prefix count and the total (rank/select)."""
    cnt = jax.lax.population_count(words).astype(_I32)
    incl = _inclusive_sum(cnt)
    return cnt, incl - cnt, incl[-1]


def _inclusive_max(x: jax.Array, width: int = 8) -> jax.Array:
    """Running maximum of a 1-D int array: :func:`_inclusive_sum`'s scheme (not cummax)."""
    n = x.shape[0]
    if n <= width:
        return jax.lax.cummax(x)
    rows = -(-n // width)
    y = jnp.pad(x, (0, rows * width - n)).reshape(rows, width)
    s = 1
    while s < width:
        y = jnp.maximum(y, jnp.pad(y[:, :-s], ((0, 0), (s, 0))))
        s *= 2
    before = jnp.pad(_inclusive_max(y[:, -1], width)[:-1], (1, 0))
    return jnp.maximum(y, before[:, None]).reshape(-1)[:n]


def _select(words, cnt, start, count: int, search: bool = False) -> tuple[jax.Array, jax.Array]:
    """(word, bit) of the ``q``-th set bit for ``q = 0 .. count - 1``; garbage past the total.

    Word ``w`` holds set bits ``start[w] .. start[w] + cnt[w] - 1``: each non-empty word
    writes its index at its first bit's slot and a running maximum carries it on (one
    scatter, one prefix pass; ``search=True``: a binary search, ~18 dependent gathers
    per slot).  Within the word a 5-step popcount bisection.
    """
    q = jnp.arange(count, dtype=_I32)
    if search:
        w = jnp.searchsorted(start + cnt, q, side="right").astype(_I32)
        w = jnp.minimum(w, words.shape[0] - 1)
    else:
        wid = jnp.arange(words.shape[0], dtype=_I32)
        slot = jnp.where(cnt > 0, start, count)
        w = _inclusive_max(jnp.zeros((count,), _I32).at[slot].set(wid, mode="drop"))
    r = q - start[w]
    word = words[w]
    pos = jnp.zeros_like(q)
    for width in (16, 8, 4, 2, 1):
        low = jnp.right_shift(word, pos.astype(_U32)) & _U32((1 << width) - 1)
        c = jax.lax.population_count(low).astype(_I32)
        up = r >= c
        pos = pos + jnp.where(up, width, 0)
        r = r - jnp.where(up, c, 0)
    return w, pos


def _corner_word(c: jax.Array, m1: int) -> tuple[jax.Array, jax.Array]:
    """(flat word, bit) of lattice corners (..., 3) in the packed (N + 1)^3 corner set."""
    return ((c[..., 0] >> 5) * m1 + c[..., 1]) * m1 + c[..., 2], c[..., 0] & 31


def _rank(words, start, w: jax.Array, bit: jax.Array) -> jax.Array:
    """Number of set bits enumerated before (word ``w``, ``bit``): the id of a set bit."""
    below = words[w] & ((_U32(1) << bit.astype(_U32)) - _U32(1))
    return start[w] + jax.lax.population_count(below).astype(_I32)


def _keep(flag: jax.Array, tree):
    """``tree`` unchanged, computed once: a fusion barrier that XLA:CPU keeps.

    XLA:CPU expands ``optimization_barrier`` before fusing, and then copies a long
    per-quad chain (select, decode, snap) into each of its many consumers: 8x the
    work for the eight link slots of a quad.  A conditional
    on a runtime flag cannot be fused through, so its result is materialised.
    """
    return jax.lax.cond(flag, lambda t: t, lambda t: jax.tree.map(jnp.zeros_like, t), tree)


# --------------------------------------------------------------------------------------
# The mesh of one Clip-Box (3.4.2, Fig. 3.4)
# --------------------------------------------------------------------------------------


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
        vertex_words: (ceil((N + 1) / 32) (N + 1)^2,) uint32 bit set of used lattice
            corners, packed along x (bit b of word (g, y, z) is x = 32 g + b).
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
    size: int = static_field()

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
        w, bit = _corner_word(c, m1)
        vid = _rank(self.vertex_words, self.vertex_start, w, bit)
        used = ((self.vertex_words[w] >> bit.astype(_U32)) & _U32(1)) == 1
        return jnp.where(ok & used & (vid < self.vertices.shape[0]), vid, -1)


# --------------------------------------------------------------------------------------
# Voxels -> polygons, prepared for the seam (3.4.4, Fig. 3.6-3.8)
# --------------------------------------------------------------------------------------


def seam_occupancy(voxels: jax.Array) -> jax.Array:
    """Ring of one outer voxel (two inner voxels) takes the outer lattice samples (Fig. 3.7).

    The outer box samples the terrain at the even inner indices, so copying those
    samples onto the ring makes the inner surface cross the box boundary exactly
    where the outer surface does.  The six ring slabs are written in place (each
    N^2 work) rather than blending a full up-sampled copy of the box.
    :func:`voxels_to_mesh` with ``seam=True`` meshes this occupancy.

    Args:
        voxels: (N, N, N) bool box voxels, N even.
    Returns:
        (N, N, N) bool.
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


def _cell_offset(scale: jax.Array) -> jax.Array:
    """Offset of a level's lattice so its voxel cubes are centred on their samples' cells.

    Level 0's voxel at the integer point p is the unit cube [p, p + 1], the cell of
    the sample.  A level-l voxel samples the same point p but stands for 2^l cells;
    drawing it as [p, p + 2^l] would put the level's surface on average
    (2^l - 1) / 2 voxels too high (and too far along +x, +z) -- a step at every seam
    that grows with the level (slabs and box outlines).  Centring
    the cube on the sample's cell, [p + 1/2 - 2^l / 2, p + 1/2 + 2^l / 2], makes every
    level an unbiased estimate of the same surface.
    """
    return 0.5 * (1.0 - scale)


def _used_corners(o: jax.Array, n: int, seam: bool) -> jax.Array:
    """Packed lattice corners that are quad corners, (ceil((N + 1) / 32), N + 1, N + 1).

    A corner is a corner of some quad iff the box voxels among the eight around it
    are not all equal (the in-box ones form a connected block, so two of them that
    differ are face neighbours).  Clamping the block into the box repeats a voxel,
    which leaves "all equal" as it is, so this is OR != AND over the clamped block.
    With ``seam``, boundary corners are moved as :func:`_snap` moves them: one with
    an odd coordinate is never used, an all-even one is used when a boundary corner
    in ``+{0, 1}^3`` of it is.

    Args:
        o: (ceil(N / 32), N, N) packed occupancy.
    """
    m1 = n + 1
    g, gc = o.shape[0], n // 32 + 1
    gi = jnp.arange(gc, dtype=_I32)[:, None, None]

    def yz(x, op):  # op over the clamped 2x2 (y, z) block of each corner
        for axis in (1, 2):
            first = jax.lax.slice_in_dim(x, 0, 1, axis=axis)
            last = jax.lax.slice_in_dim(x, x.shape[axis] - 1, x.shape[axis], axis=axis)
            x = jnp.concatenate([first, x, last], axis=axis)
            size = x.shape[axis]
            x = op(
                jax.lax.slice_in_dim(x, 0, size - 1, axis=axis),
                jax.lax.slice_in_dim(x, 1, size, axis=axis),
            )
        return x

    def at_x(x):  # bit i <- voxel bit min(i, N - 1)
        xe = jnp.pad(x, ((0, gc - g), (0, 0), (0, 0)))
        top = (x[(n - 1) // 32] >> ((n - 1) % 32)) & _U32(1)
        return xe | jnp.where(gi == n // 32, top << (n % 32), _U32(0))

    def below_x(x):  # bit i <- voxel bit max(i - 1, 0)
        xe = jnp.pad(x, ((0, gc - g), (0, 0), (0, 0)))
        carry = jnp.pad(xe[:-1], ((1, 0), (0, 0), (0, 0))) >> 31
        return (xe << 1) | carry | jnp.where(gi == 0, x[0] & _U32(1), _U32(0))

    any_, all_ = yz(o, jnp.bitwise_or), yz(o, jnp.bitwise_and)
    used = (at_x(any_) | below_x(any_)) & ~(at_x(all_) & below_x(all_))
    if not seam:
        return used
    valid = _low_bits(m1, gc)
    ends = np.zeros(gc, np.uint32)  # the bits x = 0 and x = N
    ends[0] |= 1
    ends[n // 32] |= np.uint32(1 << (n % 32))
    c = jnp.arange(m1)
    on_end = (c == 0) | (c == n)
    even = c % 2 == 0
    boundary = jnp.where(
        (on_end[:, None] | on_end[None, :])[None], valid, jnp.asarray(ends)[:, None, None]
    )
    all_even = jnp.where((even[:, None] & even[None, :])[None], valid & _U32(0x55555555), _U32(0))
    ub = used & boundary
    spread = ub | _next(ub, 1)
    spread = spread | _next(spread, 2)
    spread = spread | _next_x(spread)
    return (used & ~boundary) | (spread & boundary & all_even)


def voxels_to_mesh(
    box: ClipBox, *, max_quads: int, max_vertices: int | None = None, seam: bool = True
) -> ClipBoxMesh:
    """Voxels -> quads between solid and air voxels with shared lattice vertices (3.4.4).

    The face and used-corner sets are computed word-parallel on the occupancy packed
    along x (32 voxels a word), compacted with a rank/select directory over the
    words; vertex ids are ranks in the used-corner set.  Cost: O(N^3 / 32) word work
    plus O(max_quads) per-quad work (so a capacity near the real quad count pays).
    The packed occupancy, the face words and the used-corner words are each computed
    once and kept: left to fusion, XLA:CPU recomputed the 32-plane packing
    inside every gather that reads them.

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
    return _voxels_to_mesh(box, max_quads=max_quads, max_vertices=max_vertices, seam=seam)


def _voxels_to_mesh(
    box: ClipBox,
    *,
    max_quads: int,
    max_vertices: int | None = None,
    seam: bool = True,
    materialize: bool = True,
    search: bool = False,
) -> ClipBoxMesh:
    """:func:`voxels_to_mesh`; ``materialize=False`` (sets left to fusion) and ``search=True``
    are earlier designs that ``experiments.clipbox_table`` measures in the same run."""
    keep = (lambda x: _keep(box.level >= 0, x)) if materialize else (lambda x: x)

    n = box.size
    m1 = n + 1
    vmax = max_quads + 16 * n if max_vertices is None else max_vertices
    occ = seam_occupancy(box.voxels) if seam else box.voxels
    o = keep(_pack_x(occ))  # (G, N, N)
    g = o.shape[0]
    # Faces between voxel p and p + e_d, one set per axis d, bit at p.
    fx = (o ^ _next_x(o)) & _low_bits(n - 1, g)
    fy = (o ^ _next(o, 1)).at[:, n - 1].set(0)
    fz = (o ^ _next(o, 2)).at[:, :, n - 1].set(0)
    words = keep(jnp.stack([fx, fy, fz]).reshape(-1))
    cnt, start, num_quads = _directory(words)
    qvalid = jnp.arange(max_quads, dtype=_I32) < num_quads
    w, b = _select(words, cnt, start, max_quads, search=search)
    # Decode word (axis, g, y, z) and bit; the voxel below the face is solid or air.
    z, y = w % n, (w // n) % n
    gg, axis = (w // (n * n)) % g, w // (n * n * g)
    lo_solid = ((o.reshape(-1)[(gg * n + y) * n + z] >> b.astype(_U32)) & _U32(1)) == 1
    x, y, z, axis, lo_solid = _keep(num_quads >= 0, (32 * gg + b, y, z, axis, lo_solid))
    on = [(axis == d).astype(_I32) for d in range(3)]
    base = [x + on[0], y + on[1], z + on[2]]  # the face lies on lattice plane p_d + 1
    # Corner k at base + du e_u + dv e_v, (u, v) = (axis + 1, axis + 2) mod 3; e_u x e_v
    # = e_axis, so counter-clockwise seen from +axis; flipped when the air is below.
    lo, hi = lo_solid.astype(_I32), 1 - lo_solid.astype(_I32)
    offsets = [(0, 0), (lo, hi), (1, 1), (hi, lo)]
    corners = []  # per corner: (x, y, z) after the seam snap, and "not moved by it"
    for du, dv in offsets:
        c = [base[0] + du * on[2] + dv * on[1], base[1] + du * on[0] + dv * on[2]]
        c.append(base[2] + du * on[1] + dv * on[0])
        if seam:  # _snap on separate coordinates
            onb = functools.reduce(jnp.logical_or, [(ci == 0) | (ci == n) for ci in c])
            own = ~onb | (((c[0] | c[1] | c[2]) & 1) == 0)
            c = [jnp.where(onb, ci & ~1, ci) for ci in c]
        else:
            own = jnp.ones_like(qvalid)
        corners.append((jnp.stack(c, -1), own & qvalid))
    corners = _keep(num_quads >= 0, corners)
    center2 = jnp.stack([2 * base[d] + 1 - on[d] for d in range(3)], -1)
    vwords = keep(_used_corners(o, n, seam).reshape(-1))
    _, vstart, num_vertices = _directory(vwords)
    ids = [jnp.where(qvalid, _rank(vwords, vstart, *_corner_word(c, m1)), vmax) for c, _ in corners]
    ids = _keep(num_quads >= 0, ids)
    i0, i1, i2, i3 = ids
    tri = jnp.stack([jnp.stack([i0, i1, i2], -1), jnp.stack([i0, i2, i3], -1)], 1).reshape(-1, 3)
    tvalid = jnp.stack([(i0 != i1) & (i1 != i2) & (i0 != i2), (i0 != i2) & (i2 != i3) & (i0 != i3)])
    tvalid = (tvalid & qvalid & (i0 < vmax) & (i1 < vmax) & (i2 < vmax) & (i3 < vmax)).T.reshape(-1)
    tri = jnp.where(tvalid[:, None], tri, 0)
    # Each vertex's lattice corner, written by every quad corner that uses it (the
    # same value, so the scatter is deterministic).
    flat = [(c[:, 0] * m1 + c[:, 1]) * m1 + c[:, 2] for c, _ in corners]
    lat = (
        jnp.zeros((vmax,), _I32)
        .at[jnp.stack(ids, 1).reshape(-1)]
        .set(jnp.stack(flat, 1).reshape(-1), mode="drop")
    )
    lattice = jnp.stack([lat // (m1 * m1), (lat // m1) % m1, lat % m1], -1)
    lattice = jnp.where((jnp.arange(vmax) < num_vertices)[:, None], lattice, 0)
    # Vertex-to-vertex links (Fig. 3.4) straight from the quads' unit lattice edges:
    # corner k links to corner k + 1 and back.  A corner moved by the seam snap has
    # no links of its own (its vertex is the snap target's), and a link to a moved
    # corner goes to its target.  Every writer of a (vertex, direction) slot writes
    # the same id, so the scatter is deterministic.
    # The quad's edges k -> k + 1 run along +a, +b, -a, -b, where (a, b) is
    # (e_u, e_v) when the solid is below and (e_v, e_u) otherwise (see offsets).
    d_a = jnp.where(lo_solid, (axis + 1) % 3, (axis + 2) % 3)
    d_b = 3 - axis - d_a
    slots, vals = [], []
    for k, (d, up) in enumerate(((d_a, 1), (d_b, 1), (d_a, 0), (d_b, 0))):
        nxt = (k + 1) % 4
        link = (ids[k] != ids[nxt]) & (ids[k] < vmax) & (ids[nxt] < vmax)
        # Flat (vertex, direction) slots; vertex id vmax lands past the end and is dropped.
        slots.append(jnp.where(corners[k][1] & link, ids[k], vmax) * 6 + 2 * d + up)
        slots.append(jnp.where(corners[nxt][1] & link, ids[nxt], vmax) * 6 + 2 * d + 1 - up)
        vals += [ids[nxt], ids[k]]
    nbrs = (
        jnp.full((vmax * 6,), -1, _I32)
        .at[jnp.stack(slots, 1).reshape(-1)]
        .set(jnp.stack(vals, 1).reshape(-1), mode="drop")
        .reshape(vmax, 6)
    )
    scale = jnp.left_shift(1, box.level).astype(jnp.float32)
    offset = _cell_offset(scale)
    if seam:
        # The seam ring holds the outer level's samples, so it is drawn with the outer
        # level's cubes; the vertices where it meets this level's own voxels (lattice
        # 2 or N - 2) take the outer offset too, so the switch is one voxel wide.
        ring = jnp.any((lattice <= 2) | (lattice >= n - 2), axis=-1, keepdims=True)
        offset = jnp.where(ring, _cell_offset(2.0 * scale), offset)
    return ClipBoxMesh(
        vertices=lattice.astype(jnp.float32) * scale + offset,
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


# --------------------------------------------------------------------------------------
# Nesting: welding the seam, hiding the inner region (3.4.5, Fig. 3.7)
# --------------------------------------------------------------------------------------


_RING_SHARE = 8  # weld_seam's compact list holds 1/8 of the vertex capacity


def weld_seam(inner: ClipBoxMesh, outer: ClipBoxMesh) -> ClipBoxMesh:
    """Welds an inner mesh onto the next outer level (3.4.5, Fig. 3.7).

    The seam ring (one outer voxel thick, see :func:`seam_occupancy`) replicates the
    outer level's voxels, so its surface is the outer surface: every inner vertex in
    the ring (lattice 0, 1, N - 1 or N on some axis) takes the outer mesh's smoothed
    position and normal, at an outer lattice vertex or the mean of the two or four
    outer vertices around an edge or face midpoint (odd inner coordinates).  The
    boundary vertices (all even, :func:`voxels_to_mesh` with ``seam=True`` snaps
    them) are therefore exact copies and both meshes share the seam.  Taking the
    whole ring, not only the boundary, matters: smoothed at the inner level's
    (half) strength, the ring's outer-sized steps would show as blocks along every
    box border.

    Args:
        inner: level-l mesh built with ``seam=True``.
        outer: level-(l+1) mesh whose box contains the inner box.
    """
    n_in = inner.size
    c = inner.lattice
    v_cap = c.shape[0]
    ring = jnp.any((c <= 1) | (c >= n_in - 1), axis=-1)
    ring &= jnp.arange(v_cap) < inner.num_vertices
    # Only ring vertices change, typically a few % of the capacity: the eight outer
    # lookups per vertex run on the ring's compacted ids, over every row only when
    # the ring outgrows the compact list.
    cap = max(v_cap // _RING_SHARE, 1)

    def compact(_):
        sel = jnp.nonzero(ring, size=cap, fill_value=v_cap)[0]
        row = jnp.minimum(sel, v_cap - 1)
        ok, pos, nrm = _ring_values(inner, outer, c[row])
        ok &= sel < v_cap
        pos = jnp.where(ok[:, None], pos, inner.vertices[row])
        nrm = jnp.where(ok[:, None], nrm, inner.normals[row])
        return (
            inner.vertices.at[sel].set(pos, mode="drop"),
            inner.normals.at[sel].set(nrm, mode="drop"),
        )

    def every_row(_):
        ok, pos, nrm = _ring_values(inner, outer, c)
        ok &= ring
        return (
            jnp.where(ok[:, None], pos, inner.vertices),
            jnp.where(ok[:, None], nrm, inner.normals),
        )

    pos, nrm = jax.lax.cond(jnp.sum(ring) <= cap, compact, every_row, None)
    return dataclasses.replace(inner, vertices=pos, normals=nrm)


def _ring_values(inner: ClipBoxMesh, outer: ClipBoxMesh, c: jax.Array):
    """Outer-surface position and normal at inner lattice points ``c`` (K, 3).

    Returns ``ok`` (K,) (every outer corner needed exists), positions and unit
    normals (K, 3) in the inner mesh's frame.
    """
    off = jnp.right_shift(inner.origin - outer.origin, outer.level)  # outer voxels
    lo = off + jnp.right_shift(c, 1)
    odd = (c & 1) == 1  # between two outer lattice vertices on this axis
    # Weight of corner k (bit a: the upper outer vertex on axis a): the corners that
    # differ only on odd axes share the vertex equally; an all-even vertex is an
    # exact copy of one outer vertex (weight 1), so the seam is bit-exact.
    weight = 1.0 / jnp.left_shift(1, jnp.sum(odd, axis=-1)).astype(jnp.float32)
    pos = jnp.zeros(c.shape, jnp.float32)
    nrm = jnp.zeros(c.shape, jnp.float32)
    ok = jnp.ones(c.shape[:1], bool)
    for k in range(8):
        pick = jnp.asarray([(k >> a) & 1 for a in range(3)], bool)
        used = jnp.all(odd | ~pick, axis=-1)  # an upper corner only on odd axes
        vid = outer.vertex_id(lo + pick)
        ok &= (vid >= 0) | ~used
        w = jnp.where(used & (vid >= 0), weight, 0.0)[:, None]
        vid = jnp.maximum(vid, 0)
        pos = pos + w * outer.vertices[vid]
        nrm = nrm + w * outer.normals[vid]
    shift = (outer.origin - inner.origin).astype(jnp.float32)
    n2 = jnp.sum(nrm * nrm, axis=-1, keepdims=True)
    nrm = jnp.where(n2 > 1e-20, nrm * jax.lax.rsqrt(jnp.maximum(n2, 1e-20)), 0.0)
    return ok, pos + shift, nrm


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
