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
import jax.numpy as jnp
import numpy as np

from experiments.common import machine, write_table
from jaxgfx import terrain as T
from jaxgfx.camera import camera_from_degrees
from jaxgfx.compose import Frame, background, composite, lambert
from jaxgfx.raster import rasterize


def viewer_at(i: int, speed: int) -> np.ndarray:
    return np.array([100 + int(40 * np.sin(i / 40.0)), 30, 50 + i * speed], np.int64)


@jax.jit
def _frame(cam, v, f, n):
    out = rasterize(cam, v, f, n)
    alb = jnp.broadcast_to(jnp.asarray((0.62, 0.56, 0.48), jnp.float32), out.color.shape)
    hit = jnp.isfinite(out.depth)[..., None]
    fr = Frame(jnp.where(hit, lambert(out.color, alb), 0.0), out.depth)
    return composite([background(cam), fr]).color


def pad(a: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((n,) + a.shape[1:], a.dtype)
    out[: a.shape[0]] = a
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=None)
    ap.add_argument("--frames", type=int, default=None)
    args = ap.parse_args(argv)
    n, levels = (32, 3) if args.quick else (64, 5)
    frames = args.frames or (60 if args.quick else 300)
    w, h = (160, 120) if args.quick else (320, 240)
    speed = 1
    print("machine:", machine())
    csg = T.random_csg_terrain(key=jax.random.PRNGKey(0), count=5_000 if args.quick else 50_000)
    pipe = T.ClipBoxPipeline(csg, size=n, levels=levels, smoothing=4)
    t0 = time.perf_counter()
    worker = T.GeometryWorker(pipe, viewer_at(0, speed))
    # Compile the shapes the worker will use before the clock starts.
    st = worker.state
    for i in range(1, 12):
        st, _ = pipe.update(st, viewer_at(i * 4, speed))
    cam = camera_from_degrees((0.0, 0.0, 0.0), 0, -15, 0, 60, w, h, 0.5, 1e5)
    v, nn, f, _ = T.level_arrays(worker.acquire()["levels"], viewer_at(0, speed))
    vcap = 1 << int(np.ceil(np.log2(2 * v.shape[0])))
    fcap = 1 << int(np.ceil(np.log2(2 * f.shape[0])))
    jax.block_until_ready(_frame(cam, pad(v, vcap), pad(f, fcap), pad(nn, vcap)))
    compile_s = time.perf_counter() - t0
    print(f"setup + compilation: {compile_s:.1f} s")
    worker.start()
    times, polys, swaps, gif = [], [], [], []
    recompiles = 0
    try:
        for i in range(frames):
            t0 = time.perf_counter()
            viewer = viewer_at(i, speed)
            worker.set_viewer(viewer)
            buf = worker.acquire()
            v, nn, f, _ = T.level_arrays(buf["levels"], viewer)
            if f.shape[0] > fcap or v.shape[0] > vcap:
                fcap = max(fcap, 1 << int(np.ceil(np.log2(f.shape[0]))))
                vcap = max(vcap, 1 << int(np.ceil(np.log2(v.shape[0]))))
                recompiles += 1
            img = _frame(cam, pad(v, vcap), pad(f, fcap), pad(nn, vcap))
            img = jax.block_until_ready(img)
            times.append(time.perf_counter() - t0)
            polys.append(int(f.shape[0]))
            swaps.append(worker.swaps)
            if i % max(1, frames // 40) == 0:
                gif.append(np.asarray(jnp.round(jnp.clip(img, 0, 1) * 255)).astype(np.uint8))
    finally:
        worker.stop()
    t = np.asarray(times)
    p = np.asarray(polys)
    tps = p / t
    upd = [s for stats in worker.stats for s in stats.values()]
    reused = np.mean([s["reused"] for s in upd]) if upd else float("nan")
    rows = dict(
        frames=frames,
        frame_ms_median=1e3 * float(np.median(t)),
        frame_ms_p95=1e3 * float(np.percentile(t, 95)),
        frame_ms_max=1e3 * float(t.max()),
        polys_k_mean=float(p.mean()) / 1e3,
        mtris_per_s_median=float(np.median(tps)) / 1e6,
        geometry_swaps=int(worker.swaps),
        box_updates=len(upd),
        reused_mean=float(reused),
        render_recompiles=recompiles,
        compile_s=compile_s,
    )
    md = [
        f"Machine: {machine()}",
        "",
        f"N = {n}, {levels} levels, {w}x{h}, {frames} frames, viewer {speed} voxel/frame "
        "along +z; renderer and geometry worker share the CPU.",
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
