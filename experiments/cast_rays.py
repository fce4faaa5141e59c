"""Ray queries on RLE voxels: ``cast_rays`` against the reference DDA and Embree, same rays.

For each scene, random rays (from a sphere around the scene towards random points in its box,
a quarter of them starting inside the box) are cast three ways in the same run:

- ``cast_rays`` (the pointer map's columns, a 2-D DDA; jitted, one batch);
- the reference 3-D DDA through the dense grid (``dda_ray_3d``, voxel by voxel, vmapped);
- Embree (open3d's ``RaycastingScene.cast_rays``, all cores) on the voxels' exposed cube
  faces, when open3d is installed (``pip install '.[bench]'``; skipped with the reason).

The table gives the share of rays whose hit or miss and voxel agree with the reference DDA,
and whose hit or miss and distance (to 1e-3 relative; rays from outside the voxels) agree
with Embree's, and millions of rays a second (best of 3, compile
excluded, which is given apart).  Scenes: the Stanford bunny and the dragon of
``../shared/data/meshes`` voxelized at R = 256 (a procedural tree without them).
``--quick``: a tree at R = 32 and 2 000 rays.

Usage::

    python -m experiments.cast_rays --out out/cast_rays
    python -m experiments.cast_rays --quick --out out/cast_rays
"""

from __future__ import annotations

import argparse
import functools
import sys
import time

import jax
import numpy as np

from experiments._rle_peers import cube_faces, make_embree
from experiments.common import DATA, best_of, machine, markdown_table, write_table
from jaxgfx import raycast as RC


def scenes(quick: bool):
    """``[(name, voxels)]``: the real meshes voxelized at R = 256, else a procedural tree."""
    out = []
    if not quick:
        import trimesh

        for name, file in (("bunny", "bun_zipper.ply"), ("dragon", "dragon_11k.ply")):
            path = DATA / "meshes" / file
            if path.is_file():
                m = trimesh.load(path, process=False)
                out.append((f"{name} R=256", RC.voxelize_mesh(m.vertices, m.faces, 256)))
    if not out:
        res = 32 if quick else 128
        out.append((f"tree R={res}", RC.procedural_tree(res, key=jax.random.key(0))))
    return out


def random_rays(shape, n: int, seed: int = 0):
    """``(origins, directions)`` (n, 3): from a sphere round the box into it; a quarter inside."""
    rng = np.random.default_rng(seed)
    size = np.asarray(shape, np.float32)
    u = rng.normal(size=(n, 3))
    origins = size / 2 + 0.6 * np.linalg.norm(size) * u / np.linalg.norm(u, axis=1, keepdims=True)
    directions = rng.uniform(0, 1, (n, 3)) * size - origins
    k = n // 4
    origins[:k] = rng.uniform(0, 1, (k, 3)) * size
    directions[:k] = rng.normal(size=(k, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)  # t is a distance
    return origins.astype(np.float32), directions.astype(np.float32)


@functools.partial(jax.jit, static_argnames=("max_steps",))
def reference_rays(occ, col, origins, directions, *, max_steps: int):
    one = functools.partial(RC.dda_ray_3d, max_steps=max_steps, far=np.inf)
    return jax.vmap(one, in_axes=(None, None, 0, 0))(occ, col, origins, directions)


def measure(name: str, vox, n: int) -> dict:
    """One scene's row: agreement with the reference DDA and Embree, and rays a second."""
    rle = RC.as_jax(RC.encode_rle(vox))
    occ, col = RC.voxels_to_dense(vox)
    o, d = random_rays(rle.shape, n)
    cast = jax.jit(RC.cast_rays)
    t0 = time.perf_counter()
    hits = jax.block_until_ready(cast(rle, o, d))
    compile_s = time.perf_counter() - t0
    ours = best_of(lambda: cast(rle, o, d))
    steps = sum(occ.shape) + 3
    ref = reference_rays(occ, col, o, d, max_steps=steps)
    ref_s = best_of(lambda: reference_rays(occ, col, o, d, max_steps=steps))
    _, t_ref, v_ref = (np.asarray(a) for a in ref)
    t, v = np.asarray(hits.t), np.asarray(hits.voxel)
    row = dict(
        scene=name,
        shape="x".join(map(str, rle.shape)),
        rays=n,
        hit_pct=round(100 * float(np.isfinite(t).mean()), 2),
        same_hit_pct=round(100 * float(np.mean(np.isfinite(t) == np.isfinite(t_ref))), 3),
        same_voxel_pct=round(100 * float(np.mean(np.all(v == v_ref, -1))), 3),
        ours_Mrays_s=round(n / ours / 1e6, 3),
        compile_s=round(compile_s, 1),
        dda_Mrays_s=round(n / ref_s / 1e6, 3),
        dda_over_ours=round(ref_s / ours, 2),
    )
    embree = make_embree(*cube_faces(vox)[:2])
    if embree is not None:
        cast_embree, tensor = embree
        rays = tensor(np.concatenate([o, d], -1))
        t_e, _ = cast_embree(rays)
        e_s = best_of(lambda: cast_embree(rays)[0])
        # Rays that start inside a voxel are hits at t = 0 here; Embree meets that voxel's
        # faces from inside.  The distance is compared on the others.
        both = np.isfinite(t) & np.isfinite(t_e) & (t > 0)
        row.update(
            embree_Mrays_s=round(n / e_s / 1e6, 3),
            ours_over_embree=round(ours / e_s, 2),
            embree_same_hit_pct=round(100 * float(np.mean(np.isfinite(t) == np.isfinite(t_e))), 3),
            embree_same_t_pct=round(
                100 * float(np.mean(np.abs(t[both] - t_e[both]) <= 1e-3 * np.maximum(t[both], 1))),
                3,
            ),
        )
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a tree at R = 32, 2 000 rays")
    ap.add_argument("--out", default="out/cast_rays", help="folder for the table")
    ap.add_argument("--rays", type=int, default=None, help="rays per scene (default 200 000)")
    args = ap.parse_args(argv)
    n = args.rays or (2_000 if args.quick else 200_000)  # quick: CI time
    rows = [measure(name, vox, n) for name, vox in scenes(args.quick)]
    cols = ["scene", "shape", "rays", "hit_pct", "same_hit_pct", "same_voxel_pct",
            "ours_Mrays_s", "compile_s", "dda_Mrays_s", "dda_over_ours", "embree_Mrays_s",
            "ours_over_embree", "embree_same_hit_pct", "embree_same_t_pct"]  # fmt: skip
    title = "cast_rays: random rays against the reference DDA and Embree"
    text = f"machine: {machine()}\n\n" + markdown_table(rows, cols)
    print(f"# {title}\n\n{text}")
    write_table(args.out, title, text, dict(machine=machine(), rows=rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
