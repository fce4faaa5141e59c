"""Unlimited terrain size (thesis 3.5.3): the same view at the origin and at x = 10^9.

Terrain functions take int32 world coordinates and meshes are stored relative to
their box origin; only ``origin - viewer`` (a small integer) becomes a float.  A
view at x = 10^9 voxels is therefore the same image, pixel for pixel, as the same
view at the origin, for terrains that repeat with a period dividing 10^9 (SAW with
modulus 1000, CSG tiled every 1000 voxels).  The baseline in the same run puts
absolute float32 world coordinates into the rasterizer (what a float engine does):
at 10^9 float32 has a spacing of 64 voxels and the picture falls apart.

    python -m experiments.far_away --quick --out out/far_away
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

FAR = 1_000_000_000


def shade(out) -> Frame:
    alb = jnp.broadcast_to(jnp.asarray((0.62, 0.56, 0.48), jnp.float32), out.color.shape)
    hit = jnp.isfinite(out.depth)[..., None]
    return Frame(jnp.where(hit, lambert(out.color, alb), 0.0), out.depth)


def image(cam, frame) -> np.ndarray:
    img = composite([background(cam), frame]).color
    return np.asarray(jnp.round(jnp.clip(img, 0.0, 1.0) * 255.0)).astype(np.uint8)


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
        "saw (Eq. 3.2, modulus 1000)": T.Intersection(
            T.SawTerrain(), T.as_terrain(lambda p: p[1] < 24)
        ),
        "csg (tiled every 1000)": T.random_csg_terrain(
            key=jax.random.PRNGKey(0),
            count=3_000,
            period=1000,
            bin_size=40,
            y_range=(-64, 128),
        ),
    }
    raster = jax.jit(rasterize)
    rows, images = [], {}
    for name, terrain in terrains.items():
        pipe = T.ClipBoxPipeline(terrain, size=n, levels=levels, smoothing=4)
        near = np.array([120, 40, 40], np.int64)
        far = near + np.array([FAR, 0, 0])
        cam = camera_from_degrees((0.0, 0.0, 0.0), 20, -25, 0, 60, w, h, 0.5, 1e5)
        t0 = time.perf_counter()
        a = T.level_views(pipe.init(near))
        b = T.level_views(pipe.init(far))
        build_s = time.perf_counter() - t0
        va, na, fa, _ = T.level_arrays(a, near)
        vb, nb, fb, _ = T.level_arrays(b, far)
        img_a = image(cam, shade(raster(cam, va, fa, na)))
        img_b = image(cam, shade(raster(cam, vb, fb, nb)))
        # Baseline: absolute float32 world coordinates and an absolute camera.
        vabs, nabs, fabs, _ = T.level_arrays(b, (0, 0, 0))
        cam_abs = camera_from_degrees(far.astype(np.float64), 20, -25, 0, 60, w, h, 0.5, 1e5)
        img_c = image(cam_abs, shade(raster(cam_abs, vabs, fabs, nabs)))
        for label, img in (("relative to viewer (ours)", img_b), ("absolute float32", img_c)):
            diff = np.abs(img.astype(int) - img_a.astype(int)).max(axis=-1)
            rows.append(
                dict(
                    terrain=name,
                    method=label,
                    differing_pixels=float(np.mean(diff > 0)),
                    max_diff=int(diff.max()),
                    triangles=int(fb.shape[0]),
                    build_s=build_s,
                )
            )
            print(rows[-1])
        key = name.split()[0]
        images[f"{key}_origin.png"] = img_a
        images[f"{key}_far.png"] = img_b
        images[f"{key}_far_float32.png"] = img_c
    md = [
        f"Machine: {machine()}",
        "",
        f"N = {n}, {levels} levels, {w}x{h}; viewer (120, 40, 40) vs (120 + 10^9, 40, 40).",
        "",
        "| terrain | far view built | differing pixels vs origin | max diff (0-255) | triangles |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        md.append(
            f"| {r['terrain']} | {r['method']} | {100 * r['differing_pixels']:.2f} % "
            f"| {r['max_diff']} | {r['triangles']} |"
        )
    text = "\n".join(md)
    print(text)
    if args.out:
        from jaxgfx.io import save_png

        write_table(args.out, "Far away (thesis 3.5.3)", text, dict(machine=machine(), rows=rows))
        for fname, img in images.items():
            save_png(os.path.join(args.out, fname), img)
    ours = [r for r in rows if r["method"].endswith("(ours)")]
    return 0 if all(r["differing_pixels"] == 0 for r in ours) else 1


if __name__ == "__main__":
    sys.exit(main())
