"""Table 4.1-style benchmark of the per-plane RLE ray caster (thesis 4.6).

For each scene: memory (bits per voxel of position data incl. pointer map and
mips, Table 4.1; bytes with colour, Table 4.2), RLE elements in the traversed
columns / processed / rendered per frame, ms per frame and processed elements
per second with 2x1 anti-aliasing (the same view rendered at 2W x H on pixels
half as wide, :func:`jaxgfx.camera.supersampled`, as in the thesis), and, in
the same run with the same cameras, the baselines: the per-pixel 3-D DDA
(``reference_render``), splatting (one camera-facing quad per surface voxel
through the rasterizer, 4.6.3) and, for meshes, the mesh's own triangles
through the rasterizer.  Ratios are baseline time / our time.  Compile time
(first call) is reported apart from the steady-state time.  The default
(``ours``) draws every scene with the scatter traversal, instance maps
included.  Beside it: the wide traversal (``wide_*``, every plane in every
step) and on the CPU its plane slots (``slots_*``), the renderer's walk for a
map beyond the scatter's limits; that walk's frames taking turns with the
default's (``ab_ours_ms``, ``ab_wide_ms``: the slots on the CPU, the wide
traversal elsewhere); and the default with the wide traversal's per-pixel
re-walk, which the scatter leaves off (``rewalk_ms``,
``RenderSettings(refine_steps=16)``).  On an accelerator the CPU's variants
(plane slots, the thesis's settings) are left out.

The peers a user would pick instead (``experiments._rle_peers``): Embree
(open3d, all cores) on the same voxels' exposed cube faces and on the
original mesh, same cameras and run, with depth / hit agreement
(``ours/embree_*`` = our time / Embree's).  A second table renders 8 bunny
views batched (loop vs ``vmap`` vs the wide and scatter traversals as one vmapped
program vs sharded over one host device per core, bit-identity checked), and a
third scales the instance count (Fig. 4.23 / 4.30): time per frame beside the
share of pixels the view covers and the elements drawn, against one instance
and against 100 (which cover about as much of the screen as 1600), at LOD bands
of 96 voxels and at
``lod_distance_for``'s one-pixel bands (``px_lod`` columns), with the one-pixel
frames and the most instances at 96 shaded side by side in ``instances.png``.
Agreement with the per-pixel DDA at near and far cameras is
``experiments.rle_quality``'s table.

Usage::

    python -m experiments.rle_bench --quick --out out/rle_bench
    python -m experiments.rle_bench --out out/rle_bench

Data credit: Stanford 3D Scanning Repository (bunny, dragon), VTK sample
data (MR / CT heads), Ken Silverman's Voxlap (untitled.vxl).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from experiments._rle_peers import batched_cameras, embree_peers, mesh_in_voxels
from experiments.common import DATA, machine
from jaxgfx import post
from jaxgfx import raycast as RC
from jaxgfx.camera import look_at, supersampled
from jaxgfx.io import atomic_write, save_png

render = jax.jit(RC.render_rle)
shade = jax.jit(post.shade_voxels)
reference = jax.jit(RC.reference_render, static_argnames=("max_steps",))
# The thesis method alone: one plane per border pixel (Eq. 4.4), each pixel
# reads its nearest ray-buffer texel, no per-pixel re-walk.
THESIS = RC.RenderSettings(oversample=1.0, neighbors=0, refine_steps=0, planes_per_voxel=0.0)
# Mip level 1 starts here (voxels), level l at LOD_DISTANCE * 2^(l-1): the band
# length (the thesis's pd, 4.5.4.1) of the instance table's first timing columns.
# In the instance views its level-1 cells span ~8 output pixels (fat far trees); the
# instance table also times RC.lod_distance_for's ~1-pixel bands (px_lod columns).
LOD_DISTANCE = 96.0
# The two traversals, timed beside the default in the same run: the wide one
# with every plane in every step (the accelerator's form), and with 512 plane
# slots of 16-column blocks (a done plane's slot takes the next plane: narrower
# steps, more of them).
WIDE = RC.RenderSettings(traversal="wide")
WIDE_SLOTS = RC.RenderSettings(traversal="wide", slots=512, block_cells=16)
REWALK = RC.RenderSettings(refine_steps=16)


def markdown(rows, headers) -> str:
    out = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for r in rows:
        cells = ("" if r.get(h) is None else str(r[h]) for h in headers)
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------


def scene_list(quick: bool, only=None):
    """(name, voxels, mesh or None, note, prebuilt RLE or None) per available scene."""
    out = _scene_list(quick)
    if only:
        # The instance rows use the tree (scene 1); keep it whatever is asked for.
        out = [sc for i, sc in enumerate(out) if sc[0] in only or i == 1]
    return out


def _scene_list(quick: bool):
    import trimesh

    out = []
    key = jax.random.key(0)
    tree_res = 48 if quick else 64
    tree = RC.procedural_tree(tree_res, key=key, depth=4)
    k = 3 if quick else 5
    forest = RC.place_instances(
        RC.encode_rle(tree), [(i, j) for i in range(k) for j in range(k)], (k, k)
    )
    out.append(
        (
            "forest",
            RC.decode_rle(forest),
            None,
            f"{k * k} trees of {tree_res}^3 (instances)",
            forest,
        )
    )
    out.append(("tree", tree, None, f"procedural, {tree_res}^3", None))
    mres = 64 if quick else 256
    if (DATA / "meshes").is_dir():
        meshes = (
            (("bunny", "bun_zipper_res2.ply"),)  # quick: the smaller scan (CI time)
            if quick
            else (
                ("bunny", "bun_zipper.ply"),
                ("dragon", "dragon_11k.ply"),
            )
        )
        for name, fname in meshes:
            m = trimesh.load(DATA / "meshes" / fname, process=False)
            vox = RC.voxelize_mesh(m.vertices, m.faces, mres)
            out.append((name, vox, m, f"{fname}, R={mres}", None))
    if (DATA / "volumes").is_dir() and not quick:
        vol, _ = RC.load_volume(DATA / "volumes" / "HeadMRVolume.mhd")
        out.append(("MR head", RC.volume_to_voxels(vol, 60, up_axis=2), None, "iso 60", None))
        ct, _ = RC.load_volume(DATA / "volumes" / "headsq" / "quarter.nhdr")
        out.append(("CT head", RC.volume_to_voxels(ct, 1000, up_axis=2), None, "iso 1000", None))
    if (DATA / "voxlap" / "untitled.vxl").is_file() and not quick:  # quick: CI time
        vxl = RC.load_vxl(DATA / "voxlap" / "untitled.vxl")
        c = 128 if quick else 384
        lo, hi = 512 - c // 2, 512 + c // 2
        crop = RC.crop_voxels(vxl, (lo, 0, lo), (hi, 256, hi))
        out.append(("untitled.vxl", crop, None, f"{c}x256x{c} crop", None))
    return out


def scene_cameras(shape, w, h, n=3):
    """A short orbit path around the scene, looking slightly down."""
    X, Y, Z = shape
    c = np.array([X / 2, Y * 0.4, Z / 2])
    r = 0.9 * max(X, Z) + 0.3 * Y
    cams = []
    for k in range(n):
        a = 0.6 + 2 * np.pi * k / n
        eye = c + np.array([r * np.sin(a), 0.45 * r + 0.3 * Y, r * np.cos(a)])
        cams.append(look_at(eye, c, fov=55, width=w, height=h, far=1e5))
    return cams


def accuracy_cameras(shape, w, h):
    """Five cameras: level (pitch 0), nearly straight down, oblique, low, close."""
    X, Y, Z = shape
    c = np.array([X / 2, Y * 0.45, Z / 2])
    r = 0.9 * max(X, Z)
    return [
        ("pitch 0", look_at([c[0] - 0.3 * r, c[1], c[2] - 1.3 * r], c, 55, w, h, far=1e5)),
        ("down 88", look_at([c[0] + 0.03 * r, Y + 1.2 * r, c[2]], [c[0], 0, c[2]], 55, w, h)),
        ("oblique", look_at(c + [1.0 * r, 0.8 * r, 0.9 * r], c, 55, w, h, far=1e5)),
        ("low", look_at(c + [-1.2 * r, -0.2 * Y, 0.5 * r], c, 55, w, h, far=1e5)),
        ("close", look_at(c + [0.5 * r, 0.3 * r, -0.6 * r], c, 60, w, h, far=1e5)),
    ]


# ---------------------------------------------------------------------------
# Baselines
# ---------------------------------------------------------------------------


def splat_quads(centers, colors, cam, size=1.2):
    """One camera-facing quad (two triangles) per surface voxel (4.6.3)."""
    from jaxgfx.camera import camera_basis

    right, up, _ = camera_basis(cam)
    hs = 0.5 * size
    offs = jnp.stack([-right - up, right - up, right + up, -right + up]) * hs
    verts = (centers[:, None, :] + offs[None]).reshape(-1, 3)
    n = centers.shape[0]
    base = 4 * jnp.arange(n, dtype=jnp.int32)[:, None]
    faces = jnp.concatenate([base + jnp.array([0, 1, 2]), base + jnp.array([0, 2, 3])], axis=0)
    attrs = jnp.repeat(colors, 4, axis=0)
    return verts, faces.astype(jnp.int32), attrs


def make_splat_fn():
    from jaxgfx.raster import rasterize

    def fn(centers, colors, cam):
        v, f, a = splat_quads(centers, colors, cam)
        return rasterize(cam, v, f, a)

    return jax.jit(fn)


def make_mesh_fn():
    from jaxgfx.raster import rasterize

    return jax.jit(lambda cam, v, f, a: rasterize(cam, v, f, a))


def steady(times_per_camera) -> float:
    """Fastest frame per camera (this shared 2-core box drifts by tens of
    percent), averaged over the cameras."""
    return float(np.mean([min(t) for t in times_per_camera]))


def clock(fn, cam) -> float:
    """Seconds of one frame, waited for."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn(cam))
    return time.perf_counter() - t0


def interleaved(fns, cams, rounds: int) -> list[float]:
    """Steady seconds per frame of each of ``fns``, their frames taking turns.

    Each round renders every camera with every function in turn, so a drift of
    the shared box lands on all of them alike (the fastest frame per camera,
    averaged over the cameras, as :func:`steady`).
    """
    times: list[list[list[float]]] = [[[] for _ in cams] for _ in fns]
    for _ in range(rounds):
        for k, fn in enumerate(fns):
            for j, cam in enumerate(cams):
                times[k][j].append(clock(fn, cam))
    return [steady(t) for t in times]


def timed(fn, cams, repeats=1):
    """(first-call seconds, steady seconds per frame, the last camera's output).

    Steady time: :func:`steady` over ``repeats`` frames per camera.  The output is
    the last camera's because the Embree peers compare against their last frame.
    """
    t0 = time.perf_counter()
    jax.block_until_ready(fn(cams[0]))
    first = time.perf_counter() - t0
    times = [[clock(fn, cam) for _ in range(repeats)] for cam in cams]
    return first, steady(times), jax.block_until_ready(fn(cams[-1]))


def agreement(out_depth, out_color, ref_depth, ref_color):
    d1, d2 = np.asarray(out_depth), np.asarray(ref_depth)
    h1, h2 = np.isfinite(d1), np.isfinite(d2)
    union = h1 | h2
    dd = np.abs(np.where(h1, d1, 0) - np.where(h2, d2, 0))
    depth_ok = (h1 == h2) & (~h1 | (dd <= 1.0))
    diff = np.abs(np.asarray(out_color) - np.asarray(ref_color))
    col_ok = (h1 == h2) & np.all(diff < 1e-3, -1)
    n = max(int(union.sum()), 1)
    return depth_ok[union].sum() / n, col_ok[union].sum() / n, int(union.sum())


# ---------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------


def run(args):
    quick = args.quick
    # Quick: a small frame (the per-pixel DDA's time grows with its pixels; CI time).
    sizes = [(64, 48)] if quick else [(512, 384), (1024, 768)]
    if args.sizes:
        sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    aa = args.aa
    base_limit = 256 * 192 if quick else 512 * 384
    n_cams = 1 if quick else 3  # quick: one camera (CI time)
    # Every method gets the same repeats, so the ratios compare like with like.
    reps = 1 if quick else 2
    print(f"machine: {machine()}")
    rows, scale_rows, batch_rows = [], [], []
    figure = []  # (label, shaded frame) of the instance rows, camera 1
    only = set(args.scenes.split(",")) if args.scenes else None
    # The walk timed beside the default: the one the renderer takes for a map beyond
    # the scatter's limits, the wide traversal (with plane slots on the CPU).
    cpu = jax.default_backend() == "cpu"
    walk = WIDE_SLOTS if cpu else WIDE
    # The default settings, or the scatter's pairs per loop step fixed (--window).
    ours_settings = RC.RenderSettings(window=args.window)
    scenes = scene_list(quick, only)
    has_mesh = any(mesh is not None for _, _, mesh, _, _ in scenes)
    splat_fn = make_splat_fn()
    mesh_fn = make_mesh_fn()
    for name, vox, mesh, note, pre in scenes:
        # CI time (--quick under a minute): the instance rows time the tree;
        # the forest row runs only when no mesh from the data folder does.
        if quick and (name == "tree" or (name == "forest" and has_mesh)):
            continue
        if only and name not in only:
            continue
        rle_np = RC.encode_rle(vox, levels=1) if pre is None else pre
        st = RC.rle_stats(RC.encode_rle(vox, levels=4) if pre is None else pre)
        rle = RC.as_jax(rle_np)
        occ, col = (jnp.asarray(a) for a in RC.voxels_to_dense(vox))
        centers = jnp.asarray(vox.coords, jnp.float32) + 0.5
        colors = jnp.asarray(vox.colors, jnp.float32) / 255.0
        for w, h in sizes:
            if w > 512 and name not in ("forest", "bunny", "untitled.vxl"):
                continue  # keep the full run within the CPU budget
            # 2x1 AA: the same view on a 2W x H grid of half-width pixels.
            cams = [supersampled(c, (aa, 1)) for c in scene_cameras(vox.shape, w, h, n_cams)]
            f_ours = lambda c, r=rle: render(r, c, settings=ours_settings)  # noqa: E731
            first, ours, out = timed(f_ours, cams, reps)
            stats = {k: int(v) for k, v in out.stats.items()}
            img, _ = post.antialias(out.color, out.depth, (aa, 1))
            assert img.shape == (h, w, 3)
            row = dict(
                scene=name,
                note=note,
                size=f"{w}x{h}" + (f" ({aa}x1 AA)" if aa > 1 else ""),
                voxels=st["voxels"],
                bits_per_voxel=round(st["bits_per_voxel"], 2),
                bytes_per_voxel=round(st["bytes_per_voxel_with_color"], 2),
                el_total_M=round(stats["elements_total"] / 1e6, 3),
                el_processed_M=round(stats["elements_processed"] / 1e6, 3),
                el_rendered_M=round(stats["elements_rendered"] / 1e6, 3),
                overflow=stats["buffer_overflow"],
                ours_ms=round(1e3 * ours, 1),
                passes=stats["passes"],
                ours_compile_s=round(first - ours, 1),
                Melem_per_s=round(stats["elements_processed"] / ours / 1e6, 2),
                iters=stats["loop_iterations"],
            )
            # The traversals side by side (same cameras, same run): time, the
            # dependent loop steps of a frame (traversal + warp + re-walk), and
            # the share of pixels where their frames and the default's agree on
            # hit / miss.  Quick: none (CI time; the tests render both traversals).
            variants = () if quick else (("wide", WIDE),)
            if not quick and cpu:  # plane slots: the CPU's form of the wide traversal
                variants += (("slots", WIDE_SLOTS),)
            if not quick:
                # The frames take turns (a few per cent is the question): the default,
                # the renderer's walk beyond the scatter's limits, and the default
                # with that walk's per-pixel re-walk (RenderSettings.refine_steps,
                # which the scatter leaves off).
                fns = {
                    "ours": f_ours,
                    "wide": lambda c, r=rle: render(r, c, settings=walk),
                    "rewalk": lambda c, r=rle: render(r, c, settings=REWALK),
                }
                for f in list(fns.values())[1:]:
                    jax.block_until_ready(f(cams[0]))
                t_ab = dict(zip(fns, interleaved(list(fns.values()), cams, 3)))
                row["ab_ours_ms"] = round(1e3 * t_ab["ours"], 1)
                row["ab_wide_ms"] = round(1e3 * t_ab["wide"], 1)
                row["ab_ours/wide"] = round(t_ab["ours"] / t_ab["wide"], 2)
                row["rewalk_ms"] = round(1e3 * t_ab["rewalk"], 1)
                row["ab_ours/rewalk"] = round(t_ab["ours"] / t_ab["rewalk"], 2)
            for label, st in variants:
                f_t = lambda c, r=rle, st=st: render(r, c, settings=st)  # noqa: E731
                _, t_t, o_t = timed(f_t, cams, reps)
                row[f"{label}_ms"] = round(1e3 * t_t, 1)
                row[f"{label}_iters"] = int(o_t.stats["loop_iterations"])
                same = np.isfinite(np.asarray(o_t.depth)) == np.isfinite(np.asarray(out.depth))
                row[f"{label}_same_hits"] = round(100 * float(same.mean()), 2)
            if w * h <= base_limit:
                if not quick and cpu:  # the thesis's settings (Eq. 4.4 planes, nearest texel)
                    f_th = lambda c, r=rle: render(r, c, settings=THESIS)  # noqa: E731
                    _, t_th, _ = timed(f_th, cams, reps)
                    row["thesis_ms"] = round(1e3 * t_th, 1)
                f_ref = lambda c, o=occ, k=col: reference(o, k, c)[0]  # noqa: E731
                _, t_ref, _ = timed(f_ref, cams, reps)
                row["dda_ms"] = round(1e3 * t_ref, 1)
                row["dda/ours"] = round(t_ref / ours, 2)
                if len(vox.coords) <= 600_000:
                    f_sp = lambda c, a=centers, b=colors: splat_fn(a, b, c)  # noqa: E731
                    _, t_sp, _ = timed(f_sp, cams, reps)
                    row["splat_ms"] = round(1e3 * t_sp, 1)
                    row["splat/ours"] = round(t_sp / ours, 2)
                for label, times, extra in embree_peers(vox, mesh, cams, out, reps):
                    t_peer = steady(times)
                    row[f"{label}_ms"] = round(1e3 * t_peer, 1)
                    row[f"ours/{label}"] = round(ours / t_peer, 2)
                    row.update(extra)
                if mesh is not None:
                    mv = jnp.asarray(mesh_in_voxels(mesh, vox.shape))
                    mf = jnp.asarray(mesh.faces, jnp.int32)
                    ma = jnp.ones_like(mv)
                    f_mesh = lambda c, a=mv, b=mf, d=ma: mesh_fn(c, a, b, d)  # noqa: E731
                    _, t_mesh, _ = timed(f_mesh, cams, reps)
                    row["mesh_ms"] = round(1e3 * t_mesh, 1)
                    row["mesh/ours"] = round(t_mesh / ours, 2)
            print(json.dumps(row))
            rows.append(row)
        if name == "bunny" and not quick:  # quick: two more compiles (CI time)
            eight = scene_cameras(vox.shape, *sizes[0], 8)
            for r in batched_cameras(rle, [supersampled(c, (aa, 1)) for c in eight]):
                print(json.dumps(r))
                batch_rows.append(r)
        # Drop the scene's dozen compiled programs: XLA:CPU maps each one's machine code
        # in over a thousand memory mappings (/proc/self/maps), and with every scene's
        # kept the full run passed Linux's 65,530 a process ("LLVM compilation error:
        # Cannot allocate memory", most of the memory free).
        jax.clear_caches()
    # Scaling with instances (Fig. 4.23 / 4.30): ours vs splatting.  One
    # fixed camera near the map's corner looks across it, so more instances
    # mean more trees behind the first; mip levels + LOD bands and the early
    # exit of the plane loop keep the traversal short.
    tree = next(v for name, v, *_ in scenes if name == "tree")  # kept by any --scenes
    variants = [] if args.no_instances else [("trees", tree)]
    if not quick and variants:
        # The thesis's forests stand on terrain: the same tree on a one-voxel
        # ground slab filling its tile, so rows looking down between the
        # crowns end on the ground instead of crossing the whole map.
        occ, col = RC.voxels_to_dense(tree)
        g_occ = np.concatenate([np.ones_like(occ[:, :1]), occ], axis=1)
        g_col = np.concatenate([np.broadcast_to(np.uint8([90, 120, 60]), col[:, :1].shape), col], 1)
        variants.append(("trees on ground tiles", RC.dense_to_voxels(g_occ, g_col, surface=False)))
        # The thesis's 1 vs 1600 test used a big object (1024^3).  The
        # bunny at R = 256, its x / z padded to multiples of 32 so that six
        # mip levels tile, asks whether a bigger object closes the gap.
        bunny = next((v for name, v, *_ in scenes if name == "bunny"), None)
        if bunny is not None:
            pad = [-(-n // 32) * 32 for n in bunny.shape]
            padded = RC.Voxels(bunny.coords, bunny.colors, (pad[0], bunny.shape[1], pad[2]))
            variants.append((f"bunnies (R={max(bunny.shape)})", padded))
    shown = variants[-1 if quick else 1][0] if variants else None  # the ground tiles
    for label, obj in variants:
        # The full mip chain (4.4.7), as far as instances allow (a tile's x / z size must
        # stay divisible by 2 ** (levels - 1)), by default as column mips: the thesis's
        # cube mips raise the one-voxel ground by 2^l - 1 voxels where each LOD band
        # starts, and the frame shows a seam line there (--mips cube).
        side = int(np.gcd(obj.shape[0], obj.shape[2]))
        rle_l = RC.encode_rle(obj, levels=(side & -side).bit_length(), mips=args.mips)
        tx, ty, tz = obj.shape
        # Quick: one instance count (each count is a map of its own size, one more
        # compiled program) and one view (CI time).
        counts = [1] if quick else [1, 100, 1600]
        w, h = (128, 96) if quick else (512, 384)
        eye = np.array([-0.6 * tx, 1.1 * ty, -0.6 * tz])
        turns = (1.0,) if quick else (1.0, 0.7)
        views = [look_at(eye, eye + [1.0, -0.35, d], 55, w, h, far=1e5) for d in turns]
        cams = [supersampled(v, (aa, 1)) for v in views]
        # LOD_DISTANCE's mip cells span ~8 output pixels here; this one ~1 (738
        # voxels at 512x384): the picture a user wants, and its cost.
        px_lod = float(RC.lod_distance_for(views[0]))
        built = []
        for n in counts:
            k = int(np.ceil(np.sqrt(n)))
            tiles = [(i, j) for i in range(k) for j in range(k)][:n]
            offs = [(i * tx, j * tz) for i, j in tiles]
            scene = RC.place_instances(rle_l, tiles, (k, k))
            st = RC.rle_stats(scene)
            jscene = RC.as_jax(scene)
            X, Y, Z = scene.shape
            r = dict(
                scene=label,
                instances=n,
                map=f"{X}x{Z}",
                voxels=st["voxels"],
                ours_bytes=st["bytes_with_color"],
            )
            fn = lambda cam, s=jscene: render(s, cam, lod_distance=LOD_DISTANCE)  # noqa: E731
            f_px = lambda cam, s=jscene, d=px_lod: render(s, cam, lod_distance=d)  # noqa: E731
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn(cams[0]))
            r["_first"] = time.perf_counter() - t0
            r["el_processed_M"] = round(int(out.stats["elements_processed"]) / 1e6, 3)
            # What the view shows, for the ratios below: a frame's cost follows its
            # covered pixels and drawn elements, and more instances
            # cover more of the screen as well as hide more behind the first.
            outs = [out] + [fn(cam) for cam in cams[1:]]
            r["el_rendered_M"] = round(int(out.stats["elements_rendered"]) / 1e6, 3)
            r["_covered"] = float(np.mean([np.isfinite(np.asarray(o.depth)).mean() for o in outs]))
            r["covered_pct"] = round(100 * r["_covered"], 1)
            n_splats = n * len(obj.coords)
            r["splat_bytes"] = n_splats * (3 * 4 + 3)
            f_sp = None
            # Quick: no instance splatting (CI time); the bunny row runs that path.
            if n_splats <= 600_000 and not quick:
                cen = np.concatenate([obj.coords + [ox, 0, oz] for ox, oz in offs]) + 0.5
                cen = jnp.asarray(cen, jnp.float32)
                colr = jnp.asarray(np.concatenate([obj.colors] * n), jnp.float32) / 255.0
                f_sp = lambda cam, a=cen, b=colr: splat_fn(a, b, cam)  # noqa: E731
                jax.block_until_ready(f_sp(cams[0]))
            out_px = f_px(cams[0])  # the same program: lod_distance is traced
            r["px_lod"] = round(px_lod, 1)
            r["px_lod_el_processed_M"] = round(int(out_px.stats["elements_processed"]) / 1e6, 3)
            r["_px_covered"] = float(np.isfinite(np.asarray(out_px.depth)).mean())
            r["px_lod_iters"] = int(out_px.stats["loop_iterations"])
            f_wpx = None
            if not quick:  # the wide traversal at the same LOD (CI time: not in quick)
                f_wpx = lambda cam, s=jscene, d=px_lod: render(
                    s, cam, lod_distance=d, settings=walk
                )  # noqa: E731
                r["wide_px_lod_iters"] = int(f_wpx(cams[0]).stats["loop_iterations"])
            built.append((r, (fn, f_px, f_wpx), f_sp, (out, out_px)))
        # Interleaved rounds: every instance count sees the same machine state,
        # so drift between sections does not skew the time / 1 instance ratios.
        t_ours = [[[] for _ in cams] for _ in built]
        t_px = [[[] for _ in cams] for _ in built]
        t_wpx = [[[] for _ in cams] for _ in built]
        # Process CPU time too: XLA:CPU splits big fused ops over both cores
        # and its idle worker spins, so on this box CPU time runs up to 2x the
        # wall time, and load from other processes disturbs it less.
        c_ours = [[[] for _ in cams] for _ in built]
        t_splat = [[[] for _ in cams] for _ in built]
        for _ in range(1 if quick else 5):
            for b, (_, (fn, f_px, f_wpx), f_sp, _) in enumerate(built):
                for i, cam in enumerate(cams):
                    c0 = time.process_time()
                    t_ours[b][i].append(clock(fn, cam))
                    c_ours[b][i].append(time.process_time() - c0)
                    t_px[b][i].append(clock(f_px, cam))
                    if f_wpx is not None:
                        t_wpx[b][i].append(clock(f_wpx, cam))
                    if f_sp is not None:
                        t_splat[b][i].append(clock(f_sp, cam))
        # Ratios against the first row (one instance).
        base, base_cpu, base_px = steady(t_ours[0]), steady(c_ours[0]), steady(t_px[0])
        base_cov = built[0][0]["_covered"]
        base_px_cov = built[0][0]["_px_covered"]
        base_wpx = steady(t_wpx[0]) if t_wpx[0][0] else None
        hundred = next((steady(t) for t, x in zip(t_ours, built) if x[0]["instances"] == 100), None)
        for b, (r, _, f_sp, _) in enumerate(built):
            ours, cpu = steady(t_ours[b]), steady(c_ours[b])
            r["covered/1 instance"] = round(r.pop("_covered") / base_cov, 2)
            if hundred is not None:
                # 100 and 1600 instances cover about the same pixels (the map's
                # first rows fill the view): what the instances behind them cost.
                r["time/100 instances"] = round(ours / hundred, 2)
            r["ours_ms"] = round(1e3 * ours, 1)
            r["ours_cpu_ms"] = round(1e3 * cpu, 1)
            r["cpu/1 instance"] = round(cpu / base_cpu, 2)
            r["ours_compile_s"] = round(r.pop("_first") - ours, 1)
            if f_sp is not None:
                t_sp = steady(t_splat[b])
                r["splat_ms"] = round(1e3 * t_sp, 1)
                r["splat/ours"] = round(t_sp / ours, 2)
            r["time/1 instance"] = round(ours / base, 2)
            px = steady(t_px[b])
            r["px_lod_ms"] = round(1e3 * px, 1)
            r["px_lod/1 instance"] = round(px / base_px, 2)
            # Per covered pixel: the time ratio over the covered-pixel ratio.
            cov_ratio = r.pop("_px_covered") / base_px_cov
            r["px_lod_per_pixel/1 instance"] = round(px / base_px / cov_ratio, 2)
            if base_wpx is not None:
                wpx = steady(t_wpx[b])
                r["wide_px_lod_ms"] = round(1e3 * wpx, 1)
                r["wide_px_lod_per_pixel/1 instance"] = round(wpx / base_wpx / cov_ratio, 2)
            print(json.dumps(r))
            scale_rows.append(r)
        # The figure: the forest as a user would show it, on its ground (quick: the
        # bare trees), shaded from the depth buffer as the thesis does (4.5.6), at
        # the pixel LOD, and last the most instances at LOD_DISTANCE (fat far trees).
        if label == shown:
            r_last, _, _, (coarse, _) = built[-1]
            frames = [(f"{r['instances']} {label}", px_out) for r, _, _, (_, px_out) in built]
            frames.append((f"{r_last['instances']} {label}, LOD {LOD_DISTANCE:g}", coarse))
            for name, out in frames:
                lit = shade(cams[0], out.color, out.depth, key=jax.random.key(0))
                img, _ = post.antialias(lit, out.depth, (aa, 1))
                figure.append((name, np.asarray(img)))
        jax.clear_caches()  # as after each scene
    bits_rows = []
    if args.bits_res and (DATA / "meshes").is_dir():
        import trimesh

        for name, fname in (("bunny", "bun_zipper.ply"), ("dragon", "dragon_11k.ply")):
            m = trimesh.load(DATA / "meshes" / fname, process=False)
            t0 = time.perf_counter()
            vox = RC.voxelize_mesh(m.vertices, m.faces, args.bits_res)
            st = RC.rle_stats(RC.encode_rle(vox, levels=int(np.log2(args.bits_res)) + 1))
            st0 = RC.rle_stats(RC.encode_rle(vox, levels=1))
            r = dict(
                scene=name,
                resolution=args.bits_res,
                shape="x".join(map(str, vox.shape)),
                voxels=st["voxels"],
                rle_elements_M=round(st["rle_elements_level0"] / 1e6, 3),
                bits_per_voxel=round(st["bits_per_voxel"], 2),
                bits_level0_only=round(st0["bits_per_voxel"], 2),
                thesis_bits_per_voxel={"bunny": 22.89, "dragon": 26.3}[name],
                bytes_per_voxel_with_color=round(st["bytes_per_voxel_with_color"], 2),
                seconds=round(time.perf_counter() - t0, 1),
            )
            print(json.dumps(r))
            bits_rows.append(r)
    return rows, batch_rows, scale_rows, bits_rows, figure


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, under a minute-ish")
    ap.add_argument("--out", default=None, help="folder for table.md / table.json")
    ap.add_argument("--bits-res", type=int, default=None,
                    help="also voxelize bunny and dragon at this resolution for bits/voxel "
                    "(default: 1024, or off with --quick)")  # fmt: skip
    ap.add_argument(
        "--scenes",
        default=None,
        help="comma-separated scene names of the main table (default: all)",
    )
    ap.add_argument(
        "--aa",
        type=int,
        default=2,
        help="horizontal supersampling (1: one ray per pixel, as Embree's)",
    )
    ap.add_argument("--no-instances", action="store_true", help="skip the instance table")
    ap.add_argument(
        "--mips",
        choices=RC.MIPS,
        default="column",
        help="mip kind of the instance table's objects (encode_rle's mips=)",
    )
    ap.add_argument("--sizes", default=None, help="frame sizes, e.g. 512x384 (default: all)")
    ap.add_argument(
        "--window",
        type=int,
        default=None,
        help="the main table's frames with RenderSettings(window=N): the scatter's pairs "
        "per loop step (default: the platform's, default_window)",
    )
    ap.add_argument(
        "--fresh-memory",
        action="store_true",
        help="leave malloc as a plain script has it (no jaxgfx.keep_freed_memory): "
        "every frame's buffers are fresh pages",
    )
    args = ap.parse_args(argv)
    # As the jaxgfx command does: XLA:CPU's calls reuse freed memory (no fresh pages).
    import jaxgfx

    if not args.fresh_memory:
        jaxgfx.keep_freed_memory()
    if args.bits_res is None:
        args.bits_res = 0 if args.quick else 1024
    if not args.quick and "host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        # One host device per core (before JAX's backends start) for the sharded
        # batch; every other row runs on device 0 as before.
        jax.config.update("jax_num_cpu_devices", len(os.sched_getaffinity(0)))
    rows, batch, scale, bits, figure = run(args)
    h1 = ["scene", "note", "size", "voxels", "bits_per_voxel", "bytes_per_voxel", "el_total_M",
          "el_processed_M", "el_rendered_M", "overflow", "ours_ms", "ours_compile_s",
          "Melem_per_s", "iters", "wide_ms", "wide_iters",
          "wide_same_hits", "slots_ms", "slots_iters", "slots_same_hits",
          "ab_ours_ms", "ab_wide_ms", "ab_ours/wide", "rewalk_ms", "ab_ours/rewalk", "thesis_ms",
          "dda_ms", "dda/ours", "splat_ms", "splat/ours", "mesh_ms",
          "mesh/ours", "embree_faces_ms", "ours/embree_faces",
          "embree_faces_agree",
          "embree_mesh_ms", "ours/embree_mesh", "embree_mesh_agree", "embree_mesh_dz"]  # fmt: skip
    h2 = ["way", "frames", "size", "ms_per_frame", "speedup_vs_loop", "median_speedup",
          "iters_per_batch", "bit_identical", "same_color", "max_depth_diff",
          "same_hits"]  # fmt: skip
    h3 = ["scene", "instances", "map", "voxels", "ours_bytes", "splat_bytes", "ours_ms",
          "time/1 instance", "covered_pct", "covered/1 instance", "time/100 instances",
          "ours_cpu_ms", "cpu/1 instance", "ours_compile_s", "el_processed_M",
          "el_rendered_M", "px_lod", "px_lod_ms", "px_lod/1 instance",
          "px_lod_per_pixel/1 instance", "px_lod_iters", "wide_px_lod_ms",
          "wide_px_lod_per_pixel/1 instance", "wide_px_lod_iters", "px_lod_el_processed_M",
          "splat_ms", "splat/ours"]  # fmt: skip
    h4 = ["scene", "resolution", "shape", "voxels", "rle_elements_M", "bits_per_voxel",
          "bits_level0_only", "thesis_bits_per_voxel", "bytes_per_voxel_with_color",
          "seconds"]  # fmt: skip
    text = (
        f"Machine: {machine()}\n\n## Table 4.1-style benchmark\n\n"
        + markdown(rows, h1)
        + "\n## Batched cameras (bunny, 8 orbit views; fastest of 9 interleaved rounds, "
        + "median of the per-round speedups)\n\n"
        + "Agreement with the per-pixel DDA (near and far cameras): `experiments.rle_quality`.\n\n"
        + markdown(batch, h2)
        + "\n## Instances (Fig. 4.23 / 4.30)\n\n"
        + markdown(scale, h3)
        + "\n## Memory at the thesis resolution (Table 4.1, position data incl. mips)\n\n"
        + markdown(bits, h4)
    )
    print(text)
    if args.out:
        out = Path(args.out)
        with atomic_write(out / "table.md") as tmp:
            tmp.write_text(text)
        data = dict(machine=machine(), rows=rows, batched=batch, instances=scale, memory=bits)
        with atomic_write(out / "table.json") as tmp:
            tmp.write_text(json.dumps(data, indent=1))
        if figure:
            # Side by side, one instance count per panel, 4-pixel gaps.
            h = figure[0][1].shape[0]
            gap = np.ones((h, 4, 3), np.float32)
            panels = [p for _, img in figure for p in (img, gap)][:-1]
            save_png(out / "instances.png", np.clip(np.concatenate(panels, axis=1), 0, 1))
            print("instances.png:", ", ".join(label for label, _ in figure))
    return 0


if __name__ == "__main__":
    sys.exit(main())
