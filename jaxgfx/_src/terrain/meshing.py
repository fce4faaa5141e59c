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

import jax
import jax.numpy as jnp

from jaxgfx._src.checks import static_field
from jaxgfx._src.terrain.clipbox import ClipBox
from jaxgfx._src.terrain.functions import _I32

__all__ = ["ClipBoxMesh", "seam_occupancy", "voxels_to_mesh", "weld_seam", "visible_faces"]


# --------------------------------------------------------------------------------------
# Bit sets: rank and select (compaction for 3.4.4)
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
        flat = (c[..., 0] * m1 + c[..., 1]) * m1 + c[..., 2]
        vid = _rank(self.vertex_words, self.vertex_start, flat)
        used = _bit(self.vertex_words, flat)
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
    that grows with the level (the "slabs" and box outlines of issue 17).  Centring
    the cube on the sample's cell, [p + 1/2 - 2^l / 2, p + 1/2 + 2^l / 2], makes every
    level an unbiased estimate of the same surface.
    """
    return 0.5 * (1.0 - scale)


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
    occ = seam_occupancy(box.voxels) if seam else box.voxels
    # Per axis d, a (N, N, N-1)-style face mask packed on its own, so the masks are
    # never concatenated; word w of axis d is global word d W_d + w.
    axis_words = []
    for d in range(3):
        lo = jax.lax.slice_in_dim(occ, 0, n - 1, axis=d)
        hi = jax.lax.slice_in_dim(occ, 1, n, axis=d)
        axis_words.append(_pack_bits((lo != hi).reshape(-1)))
    w_d = axis_words[0].shape[0]
    words = jnp.concatenate(axis_words)
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
    dirs = jnp.stack([d_a, d_b, d_a, d_b], axis=1)  # (Q, 4)
    up = jnp.asarray([1, 1, 0, 0], _I32)
    own = jnp.all(snapped == corners, axis=-1) & qvalid[:, None]
    ids_next = jnp.roll(ids, -1, axis=1)
    own_next = jnp.roll(own, -1, axis=1)
    link = (ids != ids_next) & (ids < vmax) & (ids_next < vmax)
    # Flat (vertex, direction) slots; vertex id vmax lands past the end and is dropped.
    src = jnp.concatenate(
        [
            jnp.where(own & link, ids, vmax) * 6 + 2 * dirs + up,
            jnp.where(own_next & link, ids_next, vmax) * 6 + 2 * dirs + 1 - up,
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
    ring = jnp.any((c <= 1) | (c >= n_in - 1), axis=-1)
    ring &= jnp.arange(c.shape[0]) < inner.num_vertices
    off = jnp.right_shift(inner.origin - outer.origin, outer.level)  # outer voxels
    lo = off + jnp.right_shift(c, 1)
    odd = (c & 1) == 1  # between two outer lattice vertices on this axis
    # Weight of corner k (bit a: the upper outer vertex on axis a): the corners that
    # differ only on odd axes share the vertex equally; an all-even vertex is an
    # exact copy of one outer vertex (weight 1), so the seam is bit-exact.
    weight = 1.0 / jnp.left_shift(1, jnp.sum(odd, axis=-1)).astype(jnp.float32)
    pos = jnp.zeros(inner.vertices.shape, jnp.float32)
    nrm = jnp.zeros(inner.normals.shape, jnp.float32)
    ok = ring
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
    pos = jnp.where(ok[:, None], pos + shift, inner.vertices)
    nrm = jnp.where(ok[:, None], nrm, inner.normals)
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
