"""Fig. 3.18: continuous performance of a fly-through with the geometry thread running.

The render loop (this thread) moves the viewer every frame, tells the geometry
worker, picks up the newest complete meshes through the double buffer and sync
flag (:class:`jaxgfx.terrain.GeometryWorker`) and rasterizes all levels.  Per
frame: time, polygon count, triangles per second; plotted like Fig. 3.18 and
saved as a short animation.

    python -m experiments.flythrough --quick --out out/flythrough
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import numpy as np

from experiments.common import machine, write_table
from jaxgfx import terrain as T
from jaxgfx.cli.args import CliError
from jaxgfx.cli.flythrough import check_clearance, default_path, fly, path_frames
from jaxgfx.cli.terrain import VIEWS


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick",
        action="store_true",
        help="N = 32, 3 levels, 160x120: the first 20 frames of a 60-frame flight",
    )
    ap.add_argument("--out", default=None)
    ap.add_argument("--frames", type=int, default=None)
    args = ap.parse_args(argv)
    n, levels = (32, 3) if args.quick else (64, 5)
    frames = args.frames or (60 if args.quick else 300)
    w, h = (160, 120) if args.quick else (320, 240)
    print("machine:", machine())
    csg = T.random_csg_terrain(key=jax.random.PRNGKey(0), count=5_000 if args.quick else 50_000)
    pipe = T.ClipBoxPipeline(csg, size=n, levels=levels, smoothing=4)
    # the path and renderer of `jaxgfx flythrough`: from the csg view along its heading
    # for one outer-box half-width (about one voxel per frame), clear of the rocks
    reach = n * (1 << (levels - 1)) // 2
    waypoints, pitch = default_path(csg, "csg", reach)
    if args.quick:
        # the quick boxes reach only 64 voxels: fly low over the ground plane (top at
        # y = -1), as low as the rocks on the track allow, so the boxes fill the view
        for y in range(12, int(waypoints[0, 1]), 4):
            pos, yaws = path_frames(
                np.column_stack([waypoints[:, 0], np.full(len(waypoints), y), waypoints[:, 2]]),
                frames,
            )
            try:
                check_clearance(csg, pos, option="path")
                waypoints = np.column_stack(
                    [waypoints[:, 0], np.full(len(waypoints), y), waypoints[:, 2]]
                )
                break
            except CliError:
                continue
    pos, yaws = path_frames(waypoints, frames)
    check_clearance(csg, pos, option="path")
    if args.quick and args.frames is None:
        # quick: the first 20 frames at the 60-frame flight's speed (the geometry worker
        # still swaps boxes in; drawing the frames is most of a quick run's time)
        frames = 20
        pos, yaws = pos[:frames], yaws[:frames]
    speed = float(np.linalg.norm(pos[-1] - pos[0])) / max(frames - 1, 1)
    # Compile the shapes the worker will use before the clock starts (the figure is about
    # steady-state frame times, not the first compile).
    t0 = time.perf_counter()
    anchors = np.floor(pos).astype(np.int64)
    st = pipe.init(anchors[0])
    for i in range(4, min(frames, 48), 4):
        st, _ = pipe.update(st, anchors[i])
    compile_s = time.perf_counter() - t0
    print(f"setup + compilation: {compile_s:.1f} s")
    t0 = time.perf_counter()
    film, per_frame = fly(
        pipe,
        pos,
        yaws,
        pitch,
        size=(w, h),
        fov=60.0,
        height_range=VIEWS["csg"][2],
        fog_distance=float(reach),  # the box edge fades into the horizon
        snow_line=0.8,
        wait=False,  # Fig. 3.18: the renderer never waits for the geometry thread
        progress=False,
    )
    wall_s = time.perf_counter() - t0
    times = [r["ms"] / 1e3 for r in per_frame]
    polys = [r["triangles"] for r in per_frame]
    gif = list(film[:: max(1, frames // 40)])
    upd = [r["reuse_pct"] for r in per_frame if r["reuse_pct"] is not None]
    swaps = sum(r["boxes_updated"] > 0 for r in per_frame)
    box_updates = sum(r["boxes_updated"] for r in per_frame)
    t = np.asarray(times)
    p = np.asarray(polys)
    tps = p / t
    reused = np.mean(upd) / 100 if upd else float("nan")
    rows = dict(
        frames=frames,
        frame_ms_median=1e3 * float(np.median(t)),
        frame_ms_p95=1e3 * float(np.percentile(t, 95)),
        frame_ms_max=1e3 * float(t.max()),
        polys_k_mean=float(p.mean()) / 1e3,
        mtris_per_s_median=float(np.median(tps)) / 1e6,
        geometry_swaps=int(swaps),
        box_updates=int(box_updates),
        reused_mean=float(reused),
        wall_s=wall_s,
        compile_s=compile_s,
    )
    md = [
        f"Machine: {machine()}",
        "",
        f"N = {n}, {levels} levels, {w}x{h}, {frames} frames, viewer {speed:.2f} voxel/frame "
        "on the `jaxgfx flythrough` csg path; renderer and geometry worker share the CPU "
        "(frame time: swap, colours, rasterization, shading).",
        "",
        "| metric | value |",
        "|---|---|",
    ] + [
        f"| {k} | {v:.3f} |" if isinstance(v, float) else f"| {k} | {v} |" for k, v in rows.items()
    ]
    text = "\n".join(md)
    print(text)
    if args.out:
        import imageio.v3 as iio
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from jaxgfx.io import atomic_write

        write_table(args.out, "Fly-through (Fig. 3.18)", text, dict(machine=machine(), **rows))
        fig, ax = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
        ax[0].plot(p / 1e3)
        ax[0].set_ylabel("polygons (k)")
        ax[1].plot(1e3 * t)
        ax[1].set_ylabel("time / frame (ms)")
        ax[2].plot(tps / 1e6)
        ax[2].set_ylabel("M triangles / s")
        ax[2].set_xlabel("frame")
        fig.tight_layout()
        with atomic_write(os.path.join(args.out, "flythrough.png")) as tmp:
            fig.savefig(tmp, format="png", dpi=100)
        with atomic_write(os.path.join(args.out, "flythrough.gif")) as tmp:
            iio.imwrite(tmp, np.stack(gif), extension=".gif", duration=100, loop=0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
