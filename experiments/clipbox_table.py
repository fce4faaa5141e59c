"""Table 3.1 of the thesis: Clip-Box update and render times, polygons, memory.

Upper part (one resolution N, L levels): per level, ms per update for procedural
generation (differential, 3.4.6), voxels -> polygons, smoothing, surface normals,
welding; polygons per level; render ms per level.  Lower part (N = 64 ... 192):
average time to update one box along a fly path (the thesis's "CB update avg.",
differential sampling + faces + smoothing + normals: the <= 100 ms target at
N = 128), the time to rebuild the level-0 box and the slowest level's box from
scratch, render time for all levels, total polygons, memory of the state.

Beside it, on the detail size's boxes in the same run:
``voxels_to_mesh`` against VTK FlyingEdges3D (one thread) and scikit-image marching
cubes, triangles/s and vertex-distance agreement (peers from ``.[bench]``; a missing
one is skipped with the reason printed).

The terrain is the thesis's benchmark kind: 50 000 random CSG operations (3.5.2).
Compile time is reported apart: the fly path runs twice and only the second run
(same shapes, no compilation) is timed.

    python -m experiments.clipbox_table --quick --out out/clipbox_table
"""

from __future__ import annotations

import argparse
import functools
import sys
import time

import jax
import numpy as np

from experiments.common import machine, write_table
from jaxgfx import terrain as T
from jaxgfx.camera import camera_from_degrees
from jaxgfx.raster import rasterize

STAGES = ("generation_ms", "polygons_ms", "smoothing_ms", "normals_ms", "welding_ms")


def fly_path(steps: int, step: int) -> list[np.ndarray]:
    return [np.array([100 + (i * step) // 3, 24, 50 + i * step]) for i in range(steps + 1)]


def run_path(pipe, path):
    st = pipe.init(path[0])
    per_level: dict[int, list[dict]] = {}
    t_moves = []
    for v in path[1:]:
        t0 = time.perf_counter()
        st, stats = pipe.update(st, v, timings=True)
        dt = time.perf_counter() - t0
        if stats:
            t_moves.append((dt, len(stats)))
        for lvl, s in stats.items():
            per_level.setdefault(lvl, []).append(s)
    return st, per_level, t_moves


def padded_faces(f: np.ndarray, size: int) -> np.ndarray:
    out = np.zeros((size, 3), np.int32)  # degenerate (0, 0, 0) triangles draw nothing
    out[: f.shape[0]] = f
    return out


def render_times(st, viewer, width, height, raster, one_shape=False):
    """ms to draw each level alone and all levels together (steady state).

    Each mesh is padded with degenerate triangles to its own power of two, so a
    few shapes are compiled and the padding costs at most 2x.  ``one_shape``: every
    mesh padded to the largest one's power of two, one shape to compile.
    """
    levels = T.level_views(st)
    cam = camera_from_degrees((0.0, 0.0, 0.0), 0, -15, 0, 60, width, height, 0.5, 1e5)
    arrays = [T.level_arrays([lv], viewer) for lv in levels]
    arrays.append(T.level_arrays(levels, viewer))
    f_min = max(f.shape[0] for _, _, f, _ in arrays) if one_shape else 0
    v_min = max(v.shape[0] for v, _, _, _ in arrays) if one_shape else 0
    out = []
    for v, n, f, _ in arrays:
        cap = 1 << int(np.ceil(np.log2(max(f.shape[0], f_min) + 2)))
        vcap = 1 << int(np.ceil(np.log2(max(v.shape[0], v_min) + 2)))
        vv = np.zeros((vcap, 3), np.float32)
        vv[: v.shape[0]] = v
        nn = np.zeros((vcap, 3), np.float32)
        nn[: n.shape[0]] = n
        args = (cam, vv, padded_faces(f, cap), nn)
        jax.block_until_ready(raster(*args))
        ts = []
        for _ in range(3):
            t0 = time.perf_counter()
            jax.block_until_ready(raster(*args))
            ts.append(time.perf_counter() - t0)
        out.append((1e3 * min(ts), int(f.shape[0])))
    return out[:-1], out[-1]


def memory_mb(st) -> float:
    leaves = jax.tree_util.tree_leaves(st)
    return sum(x.nbytes for x in leaves) / 2**20


def full_box_ms(pipe, st, lvl=0, repeats=3) -> tuple[float, float]:
    """(sampling ms, polygons + smoothing + normals ms) of one level-``lvl`` box from scratch."""
    box = st.boxes[lvl]
    ts = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        b = jax.block_until_ready(
            pipe.sample_fn(pipe.terrain, box.origin, int(box.level), size=pipe.size)
        )
        t1 = time.perf_counter()
        pipe.build_mesh(b, seam=pipe.levels > 1)
        ts.append((t1 - t0, time.perf_counter() - t1))
    ts = np.asarray(ts[1:])
    return 1e3 * float(np.median(ts[:, 0])), 1e3 * float(np.median(ts[:, 1]))


def subdivision_ms(pipe, st, lvl: int, key) -> tuple[float, int]:
    """Steady ms of subdivision + random midpoint displacement of one level (3.4.7)."""
    m = st.meshes[lvl]
    if lvl > 0:
        inner = st.boxes[lvl - 1]
        vis = T.visible_faces(m, inner.origin, inner.size << (lvl - 1))
    else:
        vis = m.face_valid
    args = dict(key=key, amplitude=0.25, visible=vis)
    jax.block_until_ready(pipe.subdivide_fn(m, **args))
    ts = []
    for _ in range(3):
        t0 = time.perf_counter()
        out = jax.block_until_ready(pipe.subdivide_fn(m, **args))
        ts.append(time.perf_counter() - t0)
    return 1e3 * min(ts), int(np.asarray(out.face_valid).sum())


def _vtk_flying_edges():
    """A one-thread VTK FlyingEdges3D mesher of a bool volume, or (None, reason)."""
    try:
        import vtk
        from vtk.util import numpy_support
    except ImportError as e:
        return None, f"vtk not installed ({e}); pip install '.[bench]'"
    vtk.vtkMultiThreader.SetGlobalMaximumNumberOfThreads(1)

    def mesher(vox: np.ndarray):
        img = vtk.vtkImageData()
        img.SetDimensions(vox.shape[2], vox.shape[1], vox.shape[0])  # x fastest = our z
        arr = numpy_support.numpy_to_vtk(
            np.ascontiguousarray(vox, np.uint8).ravel(), deep=1, array_type=vtk.VTK_UNSIGNED_CHAR
        )
        img.GetPointData().SetScalars(arr)
        fe = vtk.vtkFlyingEdges3D()
        fe.SetInputData(img)
        fe.SetValue(0, 0.5)
        fe.ComputeNormalsOff()
        fe.ComputeGradientsOff()
        fe.ComputeScalarsOff()

        def run():
            fe.Modified()
            fe.Update()
            out = fe.GetOutput()
            pts = numpy_support.vtk_to_numpy(out.GetPoints().GetData())[:, ::-1]  # (x, y, z)
            return pts, out.GetNumberOfPolys()

        return run

    return mesher, ""


def _skimage_marching_cubes():
    try:
        from skimage import measure
    except ImportError as e:
        return None, f"scikit-image not installed ({e}); pip install '.[bench]'"

    def mesher(vox: np.ndarray):
        f = vox.astype(np.float32)

        def run():
            v, faces, _, _ = measure.marching_cubes(f, 0.5)
            return v, len(faces)

        return run

    return mesher, ""


def _nearest(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from each point of ``a`` to the nearest point of ``b``."""
    from scipy.spatial import cKDTree

    return cKDTree(b).query(a)[0]


DESIGNS = {
    # the mesher's earlier designs, measured beside the current one (see _voxels_to_mesh)
    "design_fused_search": dict(materialize=False, search=True),
    "design_kept_search": dict(materialize=True, search=True),
}
CITED = (
    "fast-surface-nets-rs: ~20 M triangles/s per core; block-mesh-rs `visible_block_faces`: "
    "~40 M quads/s per core (their READMEs' numbers on their machines; no Python binding "
    "on PyPI to measure here)"
)


def meshing_peers(pipe, st, repeats: int = 5, with_designs: bool = True) -> list[dict]:
    """voxels_to_mesh (and its earlier designs) against VTK FlyingEdges3D and skimage
    marching cubes, per level box.

    Same volume (the box's voxels, no seam ring) and the same run, alternating rounds,
    best of ``repeats``: wall ms and process CPU ms (the peers run one thread; CPU time
    is the fairer one on a loaded machine).  Triangles/s is each mesher's own triangles
    over its time.  Agreement: distance from each peer vertex (shifted by half a voxel:
    a sample sits at a cell centre) to the nearest voxel-mesh vertex, mean and 95th
    percentile, in voxels: the iso-surface cuts the voxel faces' edges, so <= 0.71 is
    the same surface.
    """
    from jaxgfx._src.terrain.meshing import _voxels_to_mesh

    peers = {}
    for name, (make, why) in (
        ("vtk_flying_edges", _vtk_flying_edges()),
        ("skimage_marching_cubes", _skimage_marching_cubes()),
    ):
        if make is None:
            print(f"skip {name}: {why}")
        else:
            peers[name] = make
    designs = {
        k: jax.jit(functools.partial(_voxels_to_mesh, **kw), static_argnames=("max_quads", "seam"))
        for k, kw in (DESIGNS.items() if with_designs else ())
    }
    rows = []
    for lvl, box in enumerate(st.boxes):
        vox = np.asarray(box.voxels)
        if vox.all() or not vox.any():  # no surface in this box (all rock or all air)
            continue
        cap = pipe.capacity.get(lvl, pipe.max_quads)
        while True:
            m = pipe.extract_fn(box, max_quads=cap, seam=False)
            if not bool(m.overflow):
                break
            cap *= 2

        def ours(box=box, cap=cap, fn=pipe.extract_fn):
            return jax.block_until_ready(fn(box, max_quads=cap, seam=False))

        runs = {"voxels_to_mesh": ours}
        for k, fn in designs.items():
            runs[k] = functools.partial(ours, fn=fn)
        runs.update({k: make(vox) for k, make in peers.items()})
        out = {k: r() for k, r in runs.items()}
        ts: dict[str, list[tuple[float, float]]] = {k: [] for k in runs}
        for _ in range(repeats):
            for k, r in runs.items():
                t0, c0 = time.perf_counter(), time.process_time()
                r()
                ts[k].append((time.perf_counter() - t0, time.process_time() - c0))
        mesh = out["voxels_to_mesh"]
        tris = {k: int(np.asarray(mesh.face_valid).sum()) for k in ["voxels_to_mesh", *designs]}
        for k in designs:  # the same mesh
            nq = 2 * int(mesh.num_quads)
            same = np.array_equal(np.asarray(out[k].faces)[:nq], np.asarray(mesh.faces)[:nq])
            same &= np.array_equal(np.asarray(out[k].neighbors), np.asarray(mesh.neighbors))
            if not same:
                raise SystemExit(f"{k} made a different mesh at level {lvl}")
        lat = np.asarray(mesh.lattice)[: int(mesh.num_vertices)].astype(np.float64)
        row = dict(level=lvl, quads=int(mesh.num_quads), capacity=cap)
        for k, t in ts.items():
            if k in peers:
                pts, tris[k] = out[k]
                d = _nearest(np.asarray(pts, np.float64) + 0.5, lat)
                row[f"{k}_dist_mean"] = float(d.mean())
                row[f"{k}_dist_p95"] = float(np.percentile(d, 95))
            wall, cpu = min(a for a, _ in t), min(b for _, b in t)
            row[f"{k}_ms"] = 1e3 * wall
            row[f"{k}_cpu_ms"] = 1e3 * cpu
            row[f"{k}_mtris_s"] = tris[k] / wall / 1e6
            row[f"{k}_cpu_mtris_s"] = tris[k] / max(cpu, 1e-9) / 1e6
        for k in peers:
            for mine in ["voxels_to_mesh", *designs]:
                for unit in ("", "cpu_"):
                    row[f"{mine}_{unit}ratio_vs_{k}"] = (
                        row[f"{mine}_{unit}mtris_s"] / row[f"{k}_{unit}mtris_s"]
                    )
        rows.append(row)
        print(
            f"meshing level {lvl}: "
            + ", ".join(
                f"{k} {row[k + '_ms']:.1f} ms ({row[k + '_cpu_ms']:.1f} cpu) "
                f"{row[k + '_mtris_s']:.1f} Mt/s"
                for k in runs
            )
            + "".join(
                f", x{k} {row['voxels_to_mesh_ratio_vs_' + k]:.2f} "
                f"(cpu {row['voxels_to_mesh_cpu_ratio_vs_' + k]:.2f})"
                for k in peers
            )
        )
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, under a minute")
    ap.add_argument("--out", default=None, help="write table.md / table.json here")
    ap.add_argument(
        "--levels", type=int, default=None, help="nested Clip-Boxes (default 7; --quick 2)"
    )
    ap.add_argument(
        "--sizes", default=None, help="comma-separated N of the lower table (default 64,...,192)"
    )
    args = ap.parse_args(argv)
    quick = args.quick
    levels = args.levels or (2 if quick else 7)
    detail_n = 32 if quick else 128
    sizes = (32,) if quick else (64, 96, 128, 160, 192)  # quick: one pipeline to compile
    if args.sizes:
        sizes = tuple(int(v) for v in args.sizes.split(","))
    steps = 3 if quick else 24  # quick: fewer box moves, fewer slab shapes to compile
    width, height = (160, 120) if quick else (640, 480)
    print("machine:", machine())
    t0 = time.perf_counter()
    csg = T.random_csg_terrain(key=jax.random.PRNGKey(0), count=5_000 if quick else 50_000)
    print(
        f"terrain: {csg.centers.shape[0]} CSG operations, bins {csg.bins.shape}, "
        f"built in {time.perf_counter() - t0:.1f} s"
    )
    raster = jax.jit(rasterize)
    path = fly_path(steps, 4)
    rows = []
    detail = None
    peers: list[dict] = []
    for n in sorted(set(sizes) | {detail_n}):
        pipe = T.ClipBoxPipeline(csg, size=n, levels=levels)
        t0 = time.perf_counter()
        run_path(pipe, path)  # compiles every shape the timed run will use
        warm_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        st, per_level, moves = run_path(pipe, path)
        timed_s = time.perf_counter() - t0
        per_box = [full_box_ms(pipe, st, lvl) for lvl in range(levels)]
        sample_ms, mesh_ms = per_box[0]
        box_ms = sample_ms + mesh_ms
        worst = max(range(levels), key=lambda lvl: sum(per_box[lvl]))
        # quick: every level drawn at the size of all of them, one rasterizer to compile
        lvl_render, (total_render, total_polys) = render_times(
            st, path[-1], width, height, raster, one_shape=quick
        )
        upd = [1e3 * dt / k for dt, k in moves]
        reused = [s["reused"] for v in per_level.values() for s in v]
        row = dict(
            N=n,
            update_avg_ms=float(np.mean(upd)) if upd else float("nan"),
            full_box_ms=box_ms,
            full_box_sampling_ms=sample_ms,
            full_box_mesh_ms=mesh_ms,
            full_box_worst_ms=sum(per_box[worst]),
            full_box_worst_level=worst,
            render_ms=total_render,
            polys_k=total_polys / 1e3,
            memory_mb=memory_mb(st),
            reused_avg=float(np.mean(reused)) if reused else float("nan"),
            compile_s=max(warm_s - timed_s, 0.0),
        )
        rows.append(row)
        print(
            f"N={n}: update avg {row['update_avg_ms']:.0f} ms, full box {box_ms:.0f} ms, "
            f"render {total_render:.0f} ms, {total_polys / 1e3:.0f} k polys, "
            f"{row['memory_mb']:.0f} MB, reused {row['reused_avg']:.0%}, "
            f"compile ~{row['compile_s']:.0f} s"
        )
        if n == detail_n:
            peers = meshing_peers(pipe, st, with_designs=not quick)
            key = jax.random.PRNGKey(1)
            subdiv = {lvl: subdivision_ms(pipe, st, lvl, key) for lvl in range(min(2, levels))}
            detail = dict(
                N=n,
                levels={
                    lvl: {
                        **{
                            k: float(np.mean([s[k] for s in per_level.get(lvl, [])] or [0.0]))
                            for k in STAGES
                        },
                        "updates": len(per_level.get(lvl, [])),
                        "subdivision_ms": subdiv.get(lvl, (0.0, 0))[0],
                        "subdivided_polys_k": subdiv.get(lvl, (0.0, 0))[1] / 1e3,
                        "rebuild_ms": sum(per_box[lvl]),
                        "render_ms": lvl_render[lvl][0],
                        "polys_k": lvl_render[lvl][1] / 1e3,
                    }
                    for lvl in range(levels)
                },
            )
    lv = detail["levels"]
    hdr = (
        "| ClipBox "
        + str(detail["N"])
        + " | "
        + " | ".join(f"CB-{lvl + 1}" for lvl in reversed(range(levels)))
        + " |"
    )
    md = [
        f"Machine: {machine()}",
        "",
        f"Fly path: {steps} steps of 4 voxels; "
        f"{levels} levels; CSG with {csg.centers.shape[0]} operations.",
        "",
        hdr,
        "|---" * (levels + 1) + "|",
    ]
    names = dict(
        generation_ms="Procedural generation (ms)",
        polygons_ms="Voxels to polygons (ms)",
        smoothing_ms="Smoothing (ms)",
        normals_ms="Surface normals (ms)",
        welding_ms="Seam welding (ms)",
        subdivision_ms="Subdivision + fractal details (ms)",
        subdivided_polys_k="Polygons after subdivision (k)",
        updates="Updates along the path",
        rebuild_ms="Full rebuild from scratch (ms)",
        render_ms="Render (ms)",
        polys_k="Polygons (k)",
    )
    for key, label in names.items():
        vals = [lv[lvl][key] for lvl in reversed(range(levels))]
        md.append(f"| {label} | " + " | ".join(f"{v:.1f}" for v in vals) + " |")
    md += [
        "",
        "| ClipBox resolution | " + " | ".join(str(r["N"]) for r in rows) + " |",
        "|---" * (len(rows) + 1) + "|",
    ]
    for key, label in (
        ("update_avg_ms", "CB update avg. (ms)"),
        ("full_box_ms", "Full box rebuild, level 0 (ms)"),
        ("full_box_sampling_ms", "- of which sampling (ms)"),
        ("full_box_mesh_ms", "- of which polygons, smoothing, normals (ms)"),
        ("full_box_worst_ms", "Full box rebuild, slowest level (ms)"),
        ("render_ms", f"Render total (ms, {width}x{height})"),
        ("polys_k", "Polys total (k)"),
        ("memory_mb", "Memory (MB)"),
        ("reused_avg", "Reused voxels"),
        ("compile_s", "Compile (s, apart)"),
    ):
        md.append(f"| {label} | " + " | ".join(f"{r[key]:.2f}" for r in rows) + " |")
    if peers:
        keys = [k[: -len("_cpu_ms")] for k in peers[0] if k.endswith("_cpu_ms")]
        vtk = "vtk_flying_edges"
        md += [
            "",
            f"Voxels -> polygons on the same {detail['N']}^3 boxes (no seam ring), same run, "
            f"best of 5 alternating: wall ms / process CPU ms, M triangles/s (wall); the "
            "ratios are voxels_to_mesh's triangles/s over VTK FlyingEdges3D's (one thread), "
            "wall and CPU; peer vertices' distance to the nearest voxel-mesh vertex "
            "(mean / p95, voxels). The design_* columns are earlier designs of the same "
            "mesher (same mesh, checked): fused = packed sets left to XLA's fusion, "
            "search = binary-search select.",
            "",
            "| level | quads (capacity) | "
            + " | ".join(keys)
            + (" | x VTK wall | x VTK cpu" if any(vtk in k for k in keys) else "")
            + " | agreement |",
            "|---" * (len(keys) + 3 + 2 * any(vtk in k for k in keys)) + "|",
        ]
        for r in peers:
            agree = "; ".join(
                f"{k}: {r[k + '_dist_mean']:.2f} / {r[k + '_dist_p95']:.2f}"
                for k in keys
                if k + "_dist_mean" in r
            )
            cells = " | ".join(
                f"{r[k + '_ms']:.1f} / {r[k + '_cpu_ms']:.1f} ms, {r[k + '_mtris_s']:.1f}"
                for k in keys
            )
            ratio = ""
            if f"voxels_to_mesh_ratio_vs_{vtk}" in r:
                ratio = (
                    f" | {r['voxels_to_mesh_ratio_vs_' + vtk]:.2f}"
                    f" | {r['voxels_to_mesh_cpu_ratio_vs_' + vtk]:.2f}"
                )
            md.append(
                f"| {r['level']} | {r['quads']} ({r['capacity']}) | {cells}{ratio} | {agree} |"
            )
        md += ["", f"Cited, not measured here: {CITED}."]
    text = "\n".join(md)
    print(text)
    if args.out:
        write_table(
            args.out,
            "Clip-Box performance (Table 3.1)",
            text,
            dict(machine=machine(), detail=detail, sizes=rows, meshing_peers=peers),
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
