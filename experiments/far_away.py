"""Unlimited terrain size (thesis 3.5.3): the same view at the origin and at x = 10^9.

Terrain functions take int32 world coordinates and meshes are stored relative to
their box origin; only ``origin - viewer`` (a small integer) becomes a float, and the
shading's detail field is computed from the integer world position too
(``jaxgfx.terrain.render_terrain``: whole cycles per 1000 voxels).  A view at
x = 10^9 voxels is therefore the same frame, colour and depth bit for bit, as the same
view at the origin, for terrains that repeat with a period dividing 10^9 (SAW with
modulus 1000, CSG tiled every 1000 voxels, a height map tiled with ``wrap`` every
100 x 80 voxels).  The baseline in the same run puts absolute float32 world
coordinates into the renderer (what a float engine does): at 10^9 float32 has a
spacing of 64 voxels and the picture falls apart.

    python -m experiments.far_away --quick --out out/far_away
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
from jaxgfx.camera import camera_from_degrees
from jaxgfx.raster import rasterize

FAR = 1_000_000_000


def hills(rows: int, cols: int) -> np.ndarray:
    """A smooth periodic height map (sums of whole-period waves), 0..1."""
    z, x = np.mgrid[0:rows, 0:cols] / np.array([rows, cols])[:, None, None]
    h = (
        np.sin(2 * np.pi * (x + 0.3 * np.sin(2 * np.pi * z)))
        + 0.6 * np.cos(2 * np.pi * (2 * z - x))
        + 0.3 * np.sin(2 * np.pi * (3 * x + 2 * z))
    )
    return (h - h.min()) / np.ptp(h)


def image(frame) -> np.ndarray:
    return np.round(np.clip(np.asarray(frame.color), 0.0, 1.0) * 255.0).astype(np.uint8)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="N = 32, 3 levels, 160x120 (under a minute)"
    )
    ap.add_argument("--out", default=None, help="write the table (Markdown, JSON) and figures here")
    args = ap.parse_args(argv)
    n, levels = (32, 3) if args.quick else (64, 5)
    w, h = (160, 120) if args.quick else (480, 360)
    print("machine:", machine())
    terrains = {
        "saw (Eq. 3.2, modulus 1000)": (T.SawTerrain(), (0.0, 1000.0), (0, 560, 0), (135, -10)),
        "csg (tiled every 1000)": (
            T.random_csg_terrain(
                key=jax.random.PRNGKey(0),
                count=3_000,
                period=1000,
                bin_size=40,
                y_range=(-64, 128),
            ),
            (-64.0, 128.0),
            (120, 40, 40),
            (20, -25),
        ),
        "heightmap (wrap, 100 x 80)": (
            T.heightmap_terrain(hills(40, 50), cell=2, vertical_scale=24.0, wrap=True),
            (0.0, 24.0),
            (120, 40, 40),
            (20, -25),
        ),
    }
    if args.quick:  # the smoke test: the two terrains of the acceptance
        terrains.pop("csg (tiled every 1000)")
    raster = jax.jit(rasterize)
    rows, images = [], {}
    for name, (terrain, heights, viewer, (yaw, pitch)) in terrains.items():
        pipe = T.ClipBoxPipeline(terrain, size=n, levels=levels, smoothing=4)
        near = np.array(viewer, np.int64)
        if name.startswith("heightmap"):
            g = float(T.ground_height(terrain, near[0] + 0.5, near[2] + 0.5))
            near[1] = int(np.ceil(g)) + 12
        far = near + np.array([FAR, 0, 0])
        cam = camera_from_degrees((0.0, 0.0, 0.0), yaw, pitch, 0, 60, w, h, 0.5, 1e5)
        t0 = time.perf_counter()
        a = T.level_views(pipe.init(near))
        b = T.level_views(pipe.init(far))
        build_s = time.perf_counter() - t0
        kw = dict(height_range=heights, fog_distance=None, rasterize_fn=raster)
        fa = T.render_terrain(cam, a, near, **kw)
        fb = T.render_terrain(cam, b, far, **kw)
        # Baseline: absolute float32 world coordinates and an absolute camera.
        cam_abs = camera_from_degrees(far.astype(np.float64), yaw, pitch, 0, 60, w, h, 0.5, 1e5)
        fc = T.render_terrain(cam_abs, b, (0, 0, 0), **kw)
        img_a = image(fa)
        for label, fr in (("relative to viewer (ours)", fb), ("absolute float32", fc)):
            img = image(fr)
            diff = np.abs(img.astype(int) - img_a.astype(int)).max(axis=-1)
            da, db = np.asarray(fa.depth), np.asarray(fr.depth)
            rows.append(
                dict(
                    terrain=name,
                    method=label,
                    differing_pixels=float(np.mean(diff > 0)),
                    max_diff=int(diff.max()),
                    depth_identical=bool(np.array_equal(da, db)),
                    colour_identical=bool(
                        np.array_equal(np.asarray(fa.color), np.asarray(fr.color))
                    ),
                    triangles=int(T.level_arrays(b, far)[2].shape[0]),
                    build_s=build_s,
                )
            )
            print(rows[-1])
            images[f"{name.split()[0]}_{'far' if fr is fb else 'far_float32'}.png"] = img
        images[f"{name.split()[0]}_origin.png"] = img_a
    md = [
        f"Machine: {machine()}",
        "",
        f"N = {n}, {levels} levels, {w}x{h}, `render_terrain` (colours by slope, height and "
        "the detail field; no fog); each terrain's viewer (x, y, z) vs (x + 10^9, y, z): SAW "
        "from `jaxgfx terrain`'s view (0, 560, 0), the others from (120, y, 40).",
        "",
        "| terrain | far view built | differing pixels vs origin | max diff (0-255) "
        "| colour identical | depth identical | triangles |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        md.append(
            f"| {r['terrain']} | {r['method']} | {100 * r['differing_pixels']:.2f} % "
            f"| {r['max_diff']} | {r['colour_identical']} | {r['depth_identical']} "
            f"| {r['triangles']} |"
        )
    text = "\n".join(md)
    print(text)
    if args.out:
        from jaxgfx.io import save_png

        write_table(args.out, "Far away (thesis 3.5.3)", text, dict(machine=machine(), rows=rows))
        for fname, img in images.items():
            save_png(os.path.join(args.out, fname), img)
    ours = [r for r in rows if r["method"].endswith("(ours)")]
    return 0 if all(r["colour_identical"] and r["depth_identical"] for r in ours) else 1


if __name__ == "__main__":
    sys.exit(main())
