"""The real asset: the glTF sample Fox animated with our LBS, and its tail replaced by one spline.

``../shared/data/rigs/fox.glb`` (1,728 vertices, 23 joints, 4 influences per vertex).  Its skin
and clip are read with pygltflib (:func:`jaxgfx.skin.load_gltf_skin`) and animated with
:func:`jaxgfx.skin.linear_blend_skinning`.  Then the three tail joints (b_Tail01-03) are replaced
by a single spline through their origins (thesis 5.9.3: fewer control joints); the tail weight of
each vertex goes to the spline, the rest stays on its bones.  The spline's start normal follows
the b_Tail01 joint, its twist is 0.  We report the vertex deviation from the original 23-joint
LBS over the clip and render both as a PNG strip (and a GIF).

Credit: model by PixelMannen (CC0), rigging and animation by @tomkranis (CC-BY 4.0), glTF
conversion by @AsoboStudio and @scurest.

    python -m experiments.fox --quick --out out/fox
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from experiments.common import DATA, machine, markdown_table, write_table
from jaxgfx import skin

DEFAULT = DATA / "rigs" / "fox.glb"
TAIL = ("b_Tail01", "b_Tail02", "b_Tail03")
CREDIT = (
    "Fox: model by PixelMannen (CC0), rigging and animation by @tomkranis (CC-BY 4.0), glTF "
    "conversion by @AsoboStudio and @scurest."
)


def render(vertices, normals, faces, cam, color):
    """Lambert-shaded image (H, W, 3) in [0, 1] on a white background."""
    return np.asarray(_render(vertices, normals, faces, cam, jnp.asarray(color, jnp.float32)))


@jax.jit
def _render(vertices, normals, faces, cam, color):
    from jaxgfx.compose import lambert
    from jaxgfx.raster import rasterize

    out = rasterize(cam, vertices, faces, normals)
    shaded = lambert(out.color, jnp.broadcast_to(color, out.color.shape))
    return jnp.where((out.tri_id >= 0)[..., None], shaded, 1.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames, smaller images")
    ap.add_argument("--out", default=None)
    ap.add_argument("--fox", default=str(DEFAULT), help="path to fox.glb")
    args = ap.parse_args(argv)
    print(machine())
    fox = skin.load_gltf_skin(args.fox)
    names = list(fox.joint_names)
    tail = [names.index(n) for n in TAIL]
    frames = 6 if args.quick else 12
    times = np.linspace(0.0, fox.duration, frames, endpoint=False)

    lbs = jax.jit(skin.linear_blend_skinning)
    v, n = jnp.asarray(fox.vertices), jnp.asarray(fox.normals)
    j, w = jnp.asarray(fox.joints), jnp.asarray(fox.weights)

    # the tail as one spline through the rest-pose origins of its joints (jaxgfx.skin, 5.9.3)
    chain = skin.gltf_spline_chain(fox, TAIL, stiffness=3.0)
    on_tail = np.zeros(len(fox.vertices), bool)
    on_tail[np.asarray(chain.chain_vertex)] = True
    spline_tail = jax.jit(skin.skin_gltf_chain)

    size = float(np.linalg.norm(fox.vertices.max(0) - fox.vertices.min(0)))
    orig, hybrid, dev_mean, dev_max = [], [], [], []
    t0 = time.perf_counter()
    for t in times:
        pose = skin.gltf_pose(fox, chain, t)
        po, no = lbs(pose.matrices, v, n, j, w)
        ph, nh = spline_tail(chain, pose)
        d = np.linalg.norm(np.asarray(ph - po), axis=1)[on_tail] / size * 100
        dev_mean.append(d.mean())
        dev_max.append(d.max())
        orig.append((np.asarray(po), np.asarray(no)))
        hybrid.append((np.asarray(ph), np.asarray(nh)))
    seconds = time.perf_counter() - t0
    bind_err = (
        float(
            np.abs(
                np.asarray(lbs(jnp.asarray(skin.joint_matrices(fox, fox.rest_trs)), v, n, j, w)[0])
                - fox.vertices
            ).max()
        )
        / size
        * 100
    )

    rows = [
        {
            "quantity": "vertices / faces / joints",
            "value": f"{len(v)} / {len(fox.faces)} / {len(names)}",
        },
        {"quantity": "LBS of the bind pose vs bind mesh, max (% of size)", "value": bind_err},
        {
            "quantity": "tail joints replaced by one spline",
            "value": f"{len(tail)} -> 1 spline (3 control points)",
        },
        {"quantity": "vertices on the tail", "value": int(on_tail.sum())},
        {
            "quantity": "tail deviation vs 23-joint LBS, mean (% of size)",
            "value": float(np.mean(dev_mean)),
        },
        {
            "quantity": "tail deviation vs 23-joint LBS, max (% of size)",
            "value": float(np.max(dev_max)),
        },
        {"quantity": f"{frames} frames, both variants (s, incl. compile)", "value": seconds},
    ]
    md = markdown_table(rows, ["quantity", "value"])
    footer = f"\n\nFox size (bbox diagonal) {size:.3f}.  {CREDIT}\nmachine: {machine()}"
    print(md + footer)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        from jaxgfx.camera import look_at
        from jaxgfx.io import atomic_write, save_png

        lo, hi = fox.vertices.min(0), fox.vertices.max(0)
        centre = (lo + hi) / 2
        wh = (160, 120) if args.quick else (256, 192)
        cam = look_at(
            centre + np.array([size * 1.1, size * 0.35, 0.0]),
            centre,
            fov=40.0,
            width=wh[0],
            height=wh[1],
            near=0.01,
            far=100.0,
        )
        top = [render(p, nn, fox.faces, cam, (0.85, 0.5, 0.25)) for p, nn in orig]
        bottom = [render(p, nn, fox.faces, cam, (0.35, 0.55, 0.85)) for p, nn in hybrid]
        strip = np.concatenate([np.concatenate(top, 1), np.concatenate(bottom, 1)], 0)
        save_png(os.path.join(args.out, "fox_strip.png"), strip)
        import imageio.v3 as iio

        gif = [(np.concatenate([a, b], 1) * 255).astype(np.uint8) for a, b in zip(top, bottom)]
        with atomic_write(os.path.join(args.out, "fox.gif")) as tmp:
            iio.imwrite(tmp, np.stack(gif), extension=".gif", duration=120, loop=0)
        write_table(
            args.out,
            "Fox: LBS and a spline tail",
            md + footer,
            {
                "machine": machine(),
                "rows": rows,
                "deviation_mean": dev_mean,
                "deviation_max": dev_max,
                "credit": CREDIT,
            },
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
