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

__all__ = ["level_views", "level_arrays", "render_levels", "mesh_to_trimesh"]


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
            assert key is not None  # checked above: subdivide > 0 needs a key
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

    if level is not None and not 0 <= level < len(levels):
        raise ValueError(f"level must be in [0, {len(levels)}), got {level}")
    sel = list(levels) if level is None else [levels[level]]
    v, n, f, _ = level_arrays(sel, anchor)
    mesh = trimesh.Trimesh(v, f, vertex_normals=n, process=False)
    mesh.remove_unreferenced_vertices()
    return mesh
