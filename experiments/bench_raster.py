"""Rasterizer throughput vs trimesh ray casting of the same depth image.

For the Stanford bunny (69 k triangles, from ../shared/data, or an icosphere of
similar size when the data is absent) and a procedural ~700 k-triangle terrain
heightfield (thesis Table 3.1 scale), at 512x384 and 1024x768: compile time,
ms per frame, triangles per second, and, in the same run, trimesh's ray
caster (the independent peer) on a random sample of the frame's pixel rays,
extrapolated to the whole frame.  The agreement column checks both produce
the same depth on the sampled pixels.

    python -m experiments.bench_raster [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np
import trimesh

from experiments.common import DATA, machine, markdown_table, time_jitted, write_table
from jaxgfx.camera import camera_basis, look_at, pixel_rays
from jaxgfx.compose import depth_image
from jaxgfx.io import load_mesh, save_png
from jaxgfx.raster import rasterize
from jaxgfx.scene import grid_faces


def heightfield(n: int) -> trimesh.Trimesh:
    """An n x n-vertex rolling terrain, 2 (n-1)^2 triangles, deterministic."""
    x, z = np.meshgrid(np.linspace(-50, 50, n), np.linspace(0, 100, n))
    y = 3 * np.sin(x / 5) * np.cos(z / 7) + 1.5 * np.sin(x / 1.7 + z / 2.3)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    return trimesh.Trimesh(v, grid_faces(n), process=False)


def scenes(quick: bool):
    bunny = DATA / "meshes" / "bun_zipper.ply"
    if bunny.exists():
        m = load_mesh(bunny)
        name = "bunny (Stanford, 69k)"
    else:
        m = trimesh.creation.icosphere(subdivisions=6)
        name = "icosphere (bunny data absent)"
    lo, hi = m.bounds
    c = 0.5 * (lo + hi)
    r = 0.5 * float(np.linalg.norm(hi - lo))
    yield name, m, dict(eye=c + r * np.array([0.4, 0.4, 2.4]), target=c, near=0.01 * r, far=100 * r)
    n = 200 if quick else 600
    t = heightfield(n)
    yield (
        f"terrain heightfield ({len(t.faces) // 1000}k)",
        t,
        dict(
            eye=np.array([0.0, 12.0, -5.0]), target=np.array([0.0, 0.0, 40.0]), near=0.1, far=500.0
        ),
    )


def peer_depth(mesh, cam, max_rays: int, budget_s: float, seed: int = 0):
    """trimesh ray casting of a random sample of the camera's pixel rays.

    Rays are cast in batches of 64 until ``max_rays`` or ``budget_s`` seconds
    are reached (trimesh without embree is slow on long grazing rays).

    Returns:
        (ray indices, depth per sampled ray, seconds spent).
    """
    o, d = (np.asarray(a, np.float64).reshape(-1, 3) for a in pixel_rays(cam, normalize=True))
    order = np.random.default_rng(seed).permutation(len(o))[:max_rays]
    fwd = np.asarray(camera_basis(cam)[2], np.float64)
    depth = np.full(len(order), np.inf)
    spent, done = 0.0, 0
    while done < len(order) and spent < budget_s:
        sl = order[done : done + 64]
        t0 = time.perf_counter()
        loc, ri, _ = mesh.ray.intersects_location(o[sl], d[sl], multiple_hits=False)
        spent += time.perf_counter() - t0
        depth[done + ri] = (loc - o[sl][ri]) @ fwd
        done += len(sl)
    return order[:done], depth[:done], spent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true", help="small sizes, < 1 minute on 2 CPU cores")
    ap.add_argument("--out", default=None, help="directory for table (md/json) and figures (png)")
    args = ap.parse_args(argv)
    sizes = [(256, 192)] if args.quick else [(512, 384), (1024, 768)]
    n_rays, budget = (512, 3.0) if args.quick else (20000, 30.0)
    raster = jax.jit(rasterize)
    rows = []
    for name, mesh, view in scenes(args.quick):
        v = np.asarray(mesh.vertices, np.float32)
        f = np.asarray(mesh.faces, np.int32)
        for w, h in sizes:
            cam = look_at(view["eye"], view["target"], 50.0, w, h, view["near"], view["far"])
            compile_s, steady, out = time_jitted(
                raster, cam, v, f, v, repeats=2 if args.quick else 3
            )
            idx, ref, peer_s = peer_depth(mesh, cam, n_rays, budget)
            ours = np.asarray(out.depth).reshape(-1)[idx]
            fin = np.isfinite(ref)
            span = (ref[fin].max() - ref[fin].min()) if fin.any() else 1.0
            agree = np.mean(
                (np.isinf(ours) & ~fin)
                | (
                    fin
                    & np.isfinite(ours)
                    & (np.abs(np.where(fin, ours, 0) - np.where(fin, ref, 0)) <= 1e-3 * span)
                )
            )
            peer_frame = peer_s * (w * h) / len(idx)
            rows.append(
                dict(
                    mesh=name,
                    triangles=len(f),
                    size=f"{w}x{h}",
                    compile_s=f"{compile_s - steady:.2f}",
                    ms_per_frame=f"{steady * 1e3:.1f}",
                    Mtri_per_s=f"{len(f) / steady / 1e6:.2f}",
                    trimesh_ms_per_frame=f"{peer_frame * 1e3:.0f}",
                    speedup_vs_trimesh=f"{peer_frame / steady:.1f}x",
                    peer_rays=len(idx),
                    depth_agree=f"{agree * 100:.2f}%",
                    coverage=f"{np.isfinite(np.asarray(out.depth)).mean() * 100:.1f}%",
                )
            )
            if args.out:
                tag = "bunny" if "bunny" in name or "ico" in name else "terrain"
                save_png(Path(args.out) / f"{tag}_{w}x{h}_depth.png", depth_image(out.depth))
    meta = dict(
        machine=machine(),
        command="python -m experiments.bench_raster" + (" --quick" if args.quick else ""),
        trimesh_rays_max=n_rays,
        trimesh_budget_s=budget,
        note="compile_s excludes one steady run; trimesh time extrapolated from the sampled rays",
    )
    cols = [
        "mesh", "triangles", "size", "compile_s", "ms_per_frame", "Mtri_per_s",
        "trimesh_ms_per_frame", "speedup_vs_trimesh", "peer_rays", "depth_agree", "coverage",
    ]  # fmt: skip
    md = markdown_table(rows, cols) + f"\n\nmachine: {meta['machine']}\n\n{meta['note']}\n"
    print(md)
    if args.out:
        write_table(args.out, "Rasterizer vs trimesh ray casting", md, dict(meta, rows=rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
