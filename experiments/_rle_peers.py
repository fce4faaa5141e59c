"""Peers and batched cameras for ``experiments.rle_bench`` (the RLE ray caster, thesis 4.6).

- Embree (open3d's ``RaycastingScene``, all cores) on the voxels' exposed cube faces and on
  the original mesh: same cameras, same rays, same run, with agreement.
  Skipped with a printed reason when open3d is absent (``pip install '.[bench]'``).
- Batched cameras: a loop of ``render_rle`` calls vs ``jax.vmap(render_rle)`` on one
  device vs the batch sharded over every host device (:func:`jaxgfx.sweep.sharded_renderer`),
  in interleaved rounds, with bit-identity against the loop, and the wide
  traversal under the accelerator's vmap rule (one vmapped program), run here.
"""

from __future__ import annotations

import time

import jax
import numpy as np

from jaxgfx import raycast as RC
from jaxgfx.camera import pixel_rays, stack_cameras

__all__ = ["cube_faces", "make_embree", "camera_rays", "mesh_in_voxels", "embree_peers",
           "batched_cameras"]  # fmt: skip


def cube_faces(vox):
    """The voxels' exposed cube faces as a triangle mesh: ``(vertices, faces, voxel index)``.

    One quad (two triangles) per face whose neighbour is empty; the third
    array names each triangle's voxel (its colour).
    """
    occ = np.zeros(vox.shape, bool)
    c = np.asarray(vox.coords, np.int64)
    occ[c[:, 0], c[:, 1], c[:, 2]] = True
    pad = np.pad(occ, 1)
    ids = np.full(vox.shape, -1, np.int64)
    ids[c[:, 0], c[:, 1], c[:, 2]] = np.arange(len(c))
    verts, tris, owner = [], [], []
    for axis in range(3):
        for side in (0, 1):
            sl = [slice(1, -1)] * 3
            sl[axis] = slice(2, None) if side else slice(0, -2)
            v = np.argwhere(occ & ~pad[tuple(sl)])
            # Corners of the face: the plane x_axis = v + side, the other two axes 0/1.
            a, b = [k for k in range(3) if k != axis]
            quad = np.zeros((4, 3), np.int64)
            quad[:, axis] = side
            quad[:, a] = [0, 1, 1, 0]
            quad[:, b] = [0, 0, 1, 1]
            base = sum(len(x) for x in verts)
            verts.append((v[:, None, :] + quad[None]).reshape(-1, 3))
            q = base + 4 * np.arange(len(v))[:, None]
            tris.append(np.concatenate([q + [0, 1, 2], q + [0, 2, 3]]))
            own = ids[v[:, 0], v[:, 1], v[:, 2]]
            owner.append(np.concatenate([own, own]))
    return (np.concatenate(verts).astype(np.float32), np.concatenate(tris).astype(np.uint32),
            np.concatenate(owner))  # fmt: skip


def make_embree(verts, faces):
    """Embree (open3d ``RaycastingScene``, all cores) on a mesh: ``rays -> (depth, triangle)``.

    Rays are :func:`jaxgfx.camera.pixel_rays` with camera-z-unit directions, so
    ``t_hit`` is the camera-space depth, as ``render_rle``'s.  None (with the
    reason printed) when open3d is not installed (``pip install .[bench]``).
    """
    try:
        import open3d as o3d
    except ImportError as e:
        print(f"Embree peer skipped: open3d not importable ({e}); pip install '.[bench]'")
        return None
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(faces))

    def cast(rays):
        ans = scene.cast_rays(rays)
        return ans["t_hit"].numpy(), ans["primitive_ids"].numpy()

    return cast, o3d.core.Tensor


def camera_rays(cam):
    o, d = (np.asarray(a, np.float32) for a in pixel_rays(cam, normalize=False))
    return np.concatenate([o, d], -1)


def mesh_in_voxels(mesh, shape):
    """The mesh's vertices in voxel units, as :func:`~jaxgfx.raycast.voxelize_mesh` places them."""
    v = np.asarray(mesh.vertices, np.float64)
    lo = v.min(0)
    return ((v - lo) * (max(shape) / (v.max(0) - lo).max())).astype(np.float32)


def embree_peers(vox, mesh, cams, ours_out, reps):
    """Embree on the voxels' cube faces (and the original mesh): ``[(label, times, extra)]``.

    Same cameras and frames as ``render_rle`` in the same run; rays are built
    before timing (Embree's time is the cast alone).  ``times``: seconds per
    camera per repeat.  ``extra``: ``{label}_agree``, the share of pixels hit
    by either that both hit, for the cube faces also with depth within one
    voxel (the last camera's frame, ``ours_out``); ``embree_mesh_dz``: median
    depth of the mesh behind the voxels.  Empty (reason printed) without open3d.
    """
    peers = [("embree_faces", cube_faces(vox)[:2])]
    if mesh is not None:
        peers.append(
            ("embree_mesh", (mesh_in_voxels(mesh, vox.shape), np.asarray(mesh.faces, np.uint32)))
        )
    rays = [camera_rays(c) for c in cams]
    out = []
    for label, (v, f) in peers:
        made = make_embree(v, f)
        if made is None:
            return []
        cast, tensor = made
        trays = [tensor(r) for r in rays]
        cast(trays[0])
        times: list[list[float]] = [[] for _ in cams]
        for _ in range(reps):
            for i, r in enumerate(trays):
                t0 = time.perf_counter()
                depth, _ = cast(r)
                times[i].append(time.perf_counter() - t0)
        d1, d2 = np.asarray(ours_out.depth), depth
        h1, h2 = np.isfinite(d1), np.isfinite(d2)
        dz = np.where(h1 & h2, d2, 0) - np.where(h1 & h2, d1, 0)
        # Cube faces: the same surface, depth within one voxel.  The mesh runs
        # inside the voxel shell (about a voxel behind its faces): same pixels hit.
        ok = h1 & h2 & ((np.abs(dz) <= 1.0) if label == "embree_faces" else True)
        extra = {f"{label}_agree": round(100 * ok.sum() / max((h1 | h2).sum(), 1), 2)}
        if label == "embree_mesh":
            extra["embree_mesh_dz"] = round(float(np.median(dz[h1 & h2])), 2)
        out.append((label, times, extra))
    return out


def batched_cameras(rle, cams, rounds: int = 9) -> list[dict]:
    """Per-frame time of a loop, ``vmap`` (one device), the wide and scatter traversals as
    one vmapped program, and the sharded batch; sameness against the loop.

    Interleaved rounds, every other one in reverse order (every way sees the same
    machine state, and none always runs first); the fastest round gives the time,
    and the median over rounds of the round's time / the loop's time the ratio
    that is robust to a noisy box (a single best-of ratio moved 0.91-1.06x
    between runs of the same code).  The sharded row runs only with more than
    one device.
    """
    from jaxgfx.sweep import sharded_renderer

    one = jax.jit(RC.render_rle)
    vm = jax.jit(jax.vmap(RC.render_rle, in_axes=(None, 0)))
    # The accelerator's rule run here: the wide traversal, the frames one vmapped program.
    vector = RC.RenderSettings(traversal="wide", batching="vectorized")
    vw = jax.jit(jax.vmap(lambda r, c: RC.render_rle(r, c, settings=vector), in_axes=(None, 0)))
    # The scatter traversal, the frames one vmapped program (its few loop steps
    # run once for the batch).
    scatter = RC.RenderSettings(traversal="scatter", batching="vectorized")
    vs = jax.jit(jax.vmap(lambda r, c: RC.render_rle(r, c, settings=scatter), in_axes=(None, 0)))
    stacked = stack_cameras(cams)
    runs = {
        "loop": lambda: [one(rle, c) for c in cams],
        "vmap (1 device)": lambda: vm(rle, stacked),
        "vmap wide, vector rule (1 device)": lambda: vw(rle, stacked),
        "vmap scatter, vector rule (1 device)": lambda: vs(rle, stacked),
    }
    n_dev = len(jax.devices())
    if n_dev > 1:
        sh = sharded_renderer(lambda cam: RC.render_rle(rle, cam))
        runs[f"sharded ({n_dev} devices)"] = lambda: sh(stacked)
    # The ways whose frames advance together in one batched loop: the forced vector
    # rule, and on accelerators the default rule (``batching="auto"``) as well.
    together = {"vmap wide, vector rule (1 device)", "vmap scatter, vector rule (1 device)"}
    if jax.default_backend() != "cpu":
        together.add("vmap (1 device)")
    first = {k: jax.block_until_ready(f()) for k, f in runs.items()}
    loop_depth = np.stack([np.asarray(o.depth) for o in first["loop"]])
    loop_color = np.stack([np.asarray(o.color) for o in first["loop"]])
    times = {k: [] for k in runs}
    for i in range(rounds):
        for k in runs if i % 2 == 0 else reversed(runs):
            t0 = time.perf_counter()
            jax.block_until_ready(runs[k]())
            times[k].append(time.perf_counter() - t0)
    best = {k: min(v) for k, v in times.items()}
    rows = []
    for k in runs:
        o = first[k]
        if k == "loop":
            depth, color = loop_depth, loop_color
        else:
            depth, color = np.asarray(o.depth), np.asarray(o.color)
        same = np.array_equal(depth, loop_depth) and np.array_equal(color, loop_color)
        hit = np.isfinite(loop_depth)
        both = hit & np.isfinite(depth)
        if k == "loop":
            iters = sum(int(x.stats["loop_iterations"]) for x in o)
        elif k.startswith("sharded"):
            iters = None
        else:
            # A batched while loop runs as long as its slowest frame; frame by
            # frame (lax.map) the frames' steps add up.
            per = np.asarray(o.stats["loop_iterations"])
            iters = int(per.max() if k in together else per.sum())
        rows.append(dict(
            way=k, frames=len(cams), size=f"{cams[0].width}x{cams[0].height}",
            ms_per_frame=round(1e3 * best[k] / len(cams), 1),
            speedup_vs_loop=round(best["loop"] / best[k], 2),
            median_speedup=round(float(np.median(np.divide(times["loop"], times[k]))), 2),
            iters_per_batch=iters,
            bit_identical="yes" if same else "no",
            same_color=bool(np.array_equal(color, loop_color)),
            max_depth_diff=float(np.max(np.abs(depth[both] - loop_depth[both]), initial=0.0)),
            same_hits=round(100 * float(np.mean(np.isfinite(depth) == hit)), 2),
        ))  # fmt: skip
    return rows
