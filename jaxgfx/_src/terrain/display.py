"""Drawing the nested levels: per-level views, rendering and export (thesis 3.4.5, 3.5.3).

Each level is drawn without the region covered by the next inner box (3.4.5); the
levels are joined relative to an integer anchor so the result is as precise far from
the origin as near it (3.5.3), then drawn through the shared rasterizer (Fig. 3.1,
thread 2) or exported with trimesh.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.terrain.clipbox import NestedClipBoxes
from jaxgfx._src.terrain.meshing import visible_faces
from jaxgfx._src.terrain.postprocess import subdivide_mesh

__all__ = ["level_views", "level_arrays", "render_levels", "weld_mesh", "mesh_to_trimesh"]


# --------------------------------------------------------------------------------------
# Per-level views of the nested boxes (3.4.5, 3.4.7)
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
        per level ``dict(vertices, normals, faces, visible, origin, lattice)``;
        ``lattice`` (V, 3) int32 vertex lattice coordinates, (0, 3) where subdivided.
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
            assert key is not None  # checked above: subdivide > 0 needs a key
            sm = sub(m, key=jax.random.fold_in(key, lvl), amplitude=amplitude, visible=vis)
            verts, nrms, faces, vis = sm.vertices, sm.normals, sm.faces, sm.face_valid
            lattice = jnp.zeros((0, 3), jnp.int32)  # midpoints have no lattice point
        else:
            verts, nrms, faces, lattice = m.vertices, m.normals, m.faces, m.lattice
        out.append(
            dict(
                vertices=np.asarray(verts),
                normals=np.asarray(nrms),
                faces=np.asarray(faces),
                visible=np.asarray(vis),
                origin=np.asarray(m.origin, np.int64),
                lattice=np.asarray(lattice),
            )
        )
    return out


# --------------------------------------------------------------------------------------
# Joining, rendering and export (3.5.3, Fig. 3.1)
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
    from jaxgfx._src.compose import Frame, lambert
    from jaxgfx._src.raster import rasterize

    v, n, f, _ = level_arrays(levels, anchor)
    if f.shape[0] == 0:
        f = np.zeros((1, 3), np.int32)  # one degenerate triangle draws nothing
    fn = rasterize_fn if rasterize_fn is not None else jax.jit(rasterize)
    out = fn(cam, jnp.asarray(v), jnp.asarray(f), jnp.asarray(n))
    alb = jnp.broadcast_to(jnp.asarray(albedo, jnp.float32), out.color.shape)
    color = lambert(out.color, alb, light_dir)
    hit = jnp.isfinite(out.depth)[..., None]
    return Frame(jnp.where(hit, color, 0.0), out.depth)


def _radial_pairs(p: np.ndarray, tri: np.ndarray, lo: int, hi: int, faces: np.ndarray):
    """Pairs the faces around a non-manifold edge (lo, hi) so each pair wraps solid.

    The faces are sorted by angle around the edge; neighbours with opposite windings
    (one runs lo -> hi, the other hi -> lo) that enclose a solid wedge (behind the
    first face's outward normal) are paired, so each voxel keeps its own sheet.
    """
    d = p[hi] - p[lo]
    d = d / max(float(np.linalg.norm(d)), 1e-30)
    u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(d, u)
    f = tri[faces]
    third = f[(f != lo) & (f != hi)]
    r = p[third] - p[lo]
    ang = np.arctan2(r @ w, r @ u)
    k = np.argmax(f == lo, axis=1)
    forward = f[np.arange(len(f)), (k + 1) % 3] == hi  # the winding runs lo -> hi
    nrm = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    order = np.argsort(ang)
    m = len(order)
    best = None
    for o in (0, 1):
        pairs = [(order[(2 * i + o) % m], order[(2 * i + 1 + o) % m]) for i in range(m // 2)]
        if any(forward[a] == forward[b] for a, b in pairs):
            continue
        mid = [
            np.cos(0.5 * (ang[a] + ang[b] + (2 * np.pi if ang[b] < ang[a] else 0))) * u
            + np.sin(0.5 * (ang[a] + ang[b] + (2 * np.pi if ang[b] < ang[a] else 0))) * w
            for a, b in pairs
        ]
        solid = all(float(nrm[a] @ mm) < 0 for (a, _), mm in zip(pairs, mid))
        if best is None or solid:
            best = pairs
    if best is None:  # inconsistent windings: pair neighbours in angular order
        best = [(order[2 * i], order[2 * i + 1]) for i in range(m // 2)]
    return [(faces[a], faces[b]) for a, b in best]


def weld_mesh(vertices, normals, faces, *, separation: float = 1e-3, pairing=None):
    """One surface from the joined levels: no duplicate vertices, no edge in > 2 faces.

    Vertices at the same position (the welded seams, 3.4.5) are merged, degenerate
    and repeated triangles dropped.  Where voxels touch only along an edge, four
    faces share it; they are paired around the edge by their angle about it, every
    vertex is split into its fans of faces joined across edges, and the copies of
    a split vertex move ``separation`` of the way towards their own faces, so no
    two vertices coincide.  The only open edges left are the outer box's rim.

    Args:
        vertices: (V, 3) positions.
        normals: (V, 3) normals.
        faces: (F, 3) int vertex ids.
        separation: fraction of the way to its faces' centroid a split copy moves.
        pairing: optional (V, 3) positions to pair the faces around a shared edge by
            (default ``vertices``): the voxel lattice, where smoothed positions snapped
            onto a height map fold thin wall slivers and mislead the angular order.
    Returns:
        ``(vertices (V', 3) float32, normals (V', 3) float32, faces (F', 3) int32)``.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    v = np.asarray(vertices, np.float32)
    nv = np.asarray(normals, np.float32)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    # Exact positions: the seam vertices are bit-identical copies (weld_seam, level_arrays).
    _, first, inv = np.unique(v, axis=0, return_index=True, return_inverse=True)
    p64 = (v if pairing is None else np.asarray(pairing))[first].astype(np.float64)
    v, nv, f = v[first], nv[first], inv.reshape(-1)[f]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, keep = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    f = f[np.sort(keep)]
    if f.shape[0] == 0:
        return v[:0], nv[:0], f.astype(np.int32)
    # Wedges (face i, corner k) = 3 i + k; wedges of one vertex joined across a shared
    # edge become one vertex, so a vertex whose faces fall apart into fans is split.
    n_f = f.shape[0]
    a, b = f.reshape(-1), np.roll(f, -1, axis=1).reshape(-1)
    wa = np.arange(3 * n_f)
    wb = 3 * (wa // 3) + (wa % 3 + 1) % 3
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    w_lo, w_hi = np.where(a < b, wa, wb), np.where(a < b, wb, wa)
    key = lo * v.shape[0] + hi
    order = np.argsort(key, kind="stable")
    _, start, count = np.unique(key[order], return_index=True, return_counts=True)
    pairs = [np.stack([order[start[count == 2]], order[start[count == 2] + 1]], -1)]
    for s0, c in zip(start[count > 2], count[count > 2]):
        h = order[s0 : s0 + c]
        fp = _radial_pairs(p64, f, int(lo[h[0]]), int(hi[h[0]]), h // 3)
        by_face = {int(x // 3): int(x) for x in h}
        pairs.append(np.asarray([(by_face[x], by_face[y]) for x, y in fp], np.int64))
    he = np.concatenate(pairs).reshape(-1, 2)
    src = np.concatenate([w_lo[he[:, 0]], w_hi[he[:, 0]]])
    dst = np.concatenate([w_lo[he[:, 1]], w_hi[he[:, 1]]])
    graph = coo_matrix((np.ones(src.shape[0]), (src, dst)), shape=(3 * n_f, 3 * n_f))
    _, comp = connected_components(graph, directed=False)
    vid = f.reshape(-1)
    ids, first_w, new_f = np.unique(comp, return_index=True, return_inverse=True)
    orig = vid[first_w]
    pos = v.astype(np.float64)[orig]
    split = np.bincount(orig, minlength=v.shape[0])[orig] > 1
    if split.any():
        cen = v.astype(np.float64)[f].mean(axis=1)[
            np.arange(3 * n_f) // 3
        ]  # centroid of each wedge's face
        acc = np.zeros((ids.shape[0], 3))
        np.add.at(acc, new_f.reshape(-1), cen)
        cnt = np.bincount(new_f.reshape(-1), minlength=ids.shape[0])[:, None]
        pos = np.where(split[:, None], pos + separation * (acc / cnt - pos), pos)
    return (
        pos.astype(np.float32),
        nv[orig],
        new_f.reshape(-1, 3).astype(np.int32),
    )


def _lattice_positions(levels: Sequence[dict], anchor, level: int | None):
    """(V, 3) voxel-lattice positions of :func:`level_arrays`' vertices, or None.

    ``lattice 2^l + origin - anchor`` per level: the unsmoothed voxel geometry, whose
    edge-touching voxels :func:`weld_mesh` pairs without ambiguity.  None when a
    level has no lattice (subdivided).
    """
    anchor = np.asarray(anchor, np.int64)
    out = []
    for i, lv in enumerate(levels):
        lat = lv.get("lattice")  # absent in hand-made views; empty where subdivided
        if lat is None or lat.shape[0] != lv["vertices"].shape[0]:
            return None
        lvl = i if level is None else level
        out.append(lat.astype(np.float64) * (1 << lvl) + (lv["origin"] - anchor))
    return np.concatenate(out)


def mesh_to_trimesh(
    levels: Sequence[dict], anchor=(0, 0, 0), level: int | None = None, *, weld: bool = True
):
    """All levels (or one) as one ``trimesh.Trimesh`` for PLY/GLB/OBJ export.

    Args:
        levels: per-level views (:func:`level_views`).
        anchor: integer world position the vertices are relative to (3.5.3).
        level: export only this level.
        weld: one surface (:func:`weld_mesh`): seam vertices merged, no edge in more
            than two triangles, open edges only on the outermost box's rim.  Off:
            each level's vertices as drawn (unused ones dropped).
    """
    import trimesh

    if level is not None and not 0 <= level < len(levels):
        raise ValueError(f"level must be in [0, {len(levels)}), got {level}")
    sel = list(levels) if level is None else [levels[level]]
    v, n, f, _ = level_arrays(sel, anchor)
    if weld:
        v, n, f = weld_mesh(v, n, f, pairing=_lattice_positions(sel, anchor, level))
    mesh = trimesh.Trimesh(v, f, vertex_normals=n, process=False)
    mesh.remove_unreferenced_vertices()
    return mesh
