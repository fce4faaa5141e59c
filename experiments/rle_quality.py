"""Quality figures for the voxel renderer (thesis Fig. 4.16, 4.18, 4.19).

Renders one close view of the bunny (or a procedural tree without the data
folder) with no AA, 2x1 AA and 2x2 AA (Fig. 4.18), with and without the
depth-aware smoothing filter (Fig. 4.16), and shaded with screen-space
normals and ambient occlusion (Fig. 4.19); writes ``quality.png`` (a labelled
grid is left to the reader: columns no AA / 2x1 / 2x2, rows raw / smoothed /
shaded) and a timing table.

Every AA frame shows the same view: :func:`jaxgfx.camera.supersampled`
renders it on pixels ``1 / fx`` by ``1 / fy`` as large (2x1: half as wide, as
in the thesis), and :func:`jaxgfx.post.antialias` averages them back.

A second table is the ray caster's acceptance at every distance: agreement
with the per-pixel 3-D DDA (depth within one voxel, same colour, % of pixels
either hits) for the bunny, the dragon (R = 256) and a 384 x 256 x 384 crop
of ``untitled.vxl``, at the five near cameras of ``rle_bench`` (512 x 384) and
three far ones (256 x 192, the distance set so that the object covers about
600 / 1,500 / 4,000 pixels), with the frame's drawn elements, those its lists
lost (``overflow``; the wide walk's lists only) and its passes (``table_passes``:
the scatter's runs of planes drawn in turn through its texel table).  ``--quick``: one
near and one far camera of the small scene at the quick frame size, and the AA views
are that frame's view with pixels 2x1 and 2x2 times as large, so that every frame is
rendered on the same rays (one compiled program).
``--oversample`` and ``--planes-per-voxel`` check other plane densities than
the defaults, ``--refine-steps`` the per-pixel re-walk (the acceptance is
measured with the defaults).

Usage::

    python -m experiments.rle_quality --quick --out out/rle_quality
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from experiments.common import DATA, machine
from jaxgfx import post
from jaxgfx import raycast as RC
from jaxgfx.camera import look_at, supersampled

FAR_COVER = (600, 1500, 4000)


def far_cameras(shape, w, h, hits_at, covers=FAR_COVER):
    """Cameras looking at the scene's centre from far, each covering about ``covers[i]`` pixels.

    ``hits_at(cam)`` counts the pixels a camera sees; one trial view per
    direction sets the distance (coverage falls as 1 / distance^2).
    """
    X, Y, Z = shape
    c = np.array([X / 2, Y * 0.45, Z / 2])
    cams = []
    for k, cover in enumerate(covers):
        a = 0.4 + 2.1 * k
        d = np.array([np.sin(a), 0.3 + 0.15 * k, np.cos(a)])
        d /= np.linalg.norm(d)
        r0 = 2.0 * max(shape)
        n0 = max(hits_at(look_at(c + r0 * d, c, 50, w, h, far=1e6)), 1)
        r = r0 * np.sqrt(n0 / cover)
        cams.append((f"far {cover}px", look_at(c + r * d, c, 50, w, h, far=1e6)))
    return cams


def acceptance(quick, render, small=None):
    """Rows of the agreement table (see the module docstring)."""
    from experiments.rle_bench import accuracy_cameras, agreement

    reference = jax.jit(RC.reference_render, static_argnames=("max_steps",))
    if quick:
        name, vox, (w, h) = small
        scenes = [(name, vox, (w, h), (w, h))]
    else:
        import trimesh

        scenes = []
        for name, fname in (("bunny", "bun_zipper.ply"), ("dragon", "dragon_11k.ply")):
            path = DATA / "meshes" / fname
            if path.is_file():
                m = trimesh.load(path, process=False)
                scenes.append(
                    (name, RC.voxelize_mesh(m.vertices, m.faces, 256), (512, 384), (256, 192))
                )
        if (DATA / "voxlap" / "untitled.vxl").is_file():
            vxl = RC.load_vxl(DATA / "voxlap" / "untitled.vxl")
            crop = RC.crop_voxels(vxl, (320, 0, 320), (704, 256, 704))
            scenes.append(("untitled.vxl", crop, (512, 384), (256, 192)))
        if not scenes:
            print("acceptance table skipped: ../shared/data (bunny, dragon, untitled.vxl) absent")
    rows = []
    for name, vox, near_wh, far_wh in scenes:
        rle = RC.as_jax(RC.encode_rle(vox))
        occ, col = (jax.numpy.asarray(a) for a in RC.voxels_to_dense(vox))
        hits = lambda cam, r=rle: int(np.isfinite(np.asarray(render(r, cam).depth)).sum())  # noqa: E731
        near = accuracy_cameras(vox.shape, *near_wh)
        far = far_cameras(vox.shape, *far_wh, hits, covers=(1500,) if quick else FAR_COVER)
        for cname, cam in (near[2:3] if quick else near) + far:
            ref, _ = reference(occ, col, cam)
            out = render(rle, cam)
            df, cf, n = agreement(out.depth, out.color, ref.depth, ref.color)
            r = dict(
                scene=name,
                camera=cname,
                size=f"{cam.width}x{cam.height}",
                hit_pixels=n,
                planes=int(out.stats["planes"]),
                overflow=int(out.stats["buffer_overflow"]),
                drawn=int(out.stats["elements_rendered"]),
                table_passes=int(out.stats["passes"]),
                depth_agree=round(100 * df, 2),
                color_agree=round(100 * cf, 2),
                passes="yes" if df >= 0.99 and cf >= 0.98 else "NO",
            )
            print(json.dumps(r), flush=True)
            rows.append(r)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=None)
    ap.add_argument("--traversal", default="auto", choices=("auto", "wide", "scatter"),
                    help="RenderSettings.traversal of the renders checked")  # fmt: skip
    ap.add_argument("--oversample", type=float, default=None,
                    help="RenderSettings.oversample of the renders checked")  # fmt: skip
    ap.add_argument("--planes-per-voxel", type=float, default=None,
                    help="RenderSettings.planes_per_voxel of the renders checked")  # fmt: skip
    ap.add_argument("--refine-steps", type=int, default=None,
                    help="RenderSettings.refine_steps of the renders checked")  # fmt: skip
    args = ap.parse_args(argv)
    w, h = (96, 72) if args.quick else (256, 192)
    res = 48 if args.quick else 128
    if (DATA / "meshes" / "bun_zipper_res2.ply").is_file():
        import trimesh

        m = trimesh.load(DATA / "meshes" / "bun_zipper_res2.ply", process=False)
        vox = RC.voxelize_mesh(m.vertices, m.faces, res)
        # The mesh has no colours: a colour ramp over the box, so that the raw
        # frames show which voxel each pixel took, not one flat silhouette.
        ramp = 60 + 170 * np.asarray(vox.coords, np.float64) / np.asarray(vox.shape)
        vox = RC.make_voxels(vox.coords, ramp.astype(np.uint8), vox.shape)
        name = f"bunny R={res}"
    else:
        vox = RC.procedural_tree(res, key=jax.random.key(0))
        name = f"tree R={res}"
    X, Y, Z = vox.shape
    rle = RC.as_jax(RC.encode_rle(vox))
    c = np.array([X / 2, 0.42 * Y, Z / 2])
    # Close, with the whole object in the frame.
    eye = c + np.array([1.05 * X, 0.3 * Y, 1.15 * Z])
    tuned = dict(
        oversample=args.oversample,
        planes_per_voxel=args.planes_per_voxel,
        refine_steps=args.refine_steps,
    )
    settings = RC.RenderSettings(
        traversal=args.traversal, **{k: v for k, v in tuned.items() if v is not None}
    )
    render = jax.jit(lambda r, c: RC.render_rle(r, c, settings=settings))
    shaded = jax.jit(
        lambda cam, col, dep: post.shade(
            col,
            post.screen_space_normals(cam, dep, key=jax.random.key(1)),
            post.ambient_occlusion(dep, key=jax.random.key(2)),
        )
    )

    def view(fx, fy):
        """The view that AA ``(fx, fy)`` renders supersampled."""
        cam = look_at(eye, c, 50, w, h)
        if not args.quick:
            return cam
        # Quick: the w x h view with pixels fx by fy times as large: supersampled, it is
        # the w x h camera again, so one compiled program renders every frame (CI time).
        s = np.array([fx, fy], np.float32)
        return dataclasses.replace(cam, width=w // fx, height=h // fy,
                                   focal=cam.focal / s, principal=cam.principal / s)  # fmt: skip

    tiles, rows = [], []
    for fx, fy in ((1, 1), (2, 1), (2, 2)):
        cam = supersampled(view(fx, fy), (fx, fy))
        t0 = time.perf_counter()
        out = jax.block_until_ready(render(rle, cam))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        out = jax.block_until_ready(render(rle, cam))
        steady = time.perf_counter() - t0
        col, dep = post.antialias(out.color, out.depth, (fx, fy))
        if args.quick:
            # The coarser view's pixels drawn fx by fy times as large: the w x h grid
            # again, one shape for the filters below to compile for (CI time).
            col, dep = (np.repeat(np.repeat(a, fy, axis=0), fx, axis=1) for a in (col, dep))
        sm, sdep = post.smooth(col, dep)
        cam1 = look_at(eye, c, 50, w, h)
        sh = shaded(cam1, sm, sdep)
        tiles.append([np.asarray(col), np.asarray(sm), np.asarray(sh)])
        rows.append(dict(aa=f"{fx}x{fy}", render_ms=round(1e3 * steady, 1),
                         compile_s=round(first - steady, 1)))  # fmt: skip
    acc = acceptance(args.quick, render, small=(name, vox, (w, h)))
    grid = np.concatenate([np.concatenate(t, axis=0) for t in tiles], axis=1)
    text = f"Machine: {machine()}; scene {name}; frame {w}x{h}"
    if args.quick:
        text += " (quick: every AA view on these rays, its pixels 1x1 / 2x1 / 2x2 as large)"
    text += "\n\n| aa | render_ms | compile_s |\n"
    text += "|---|---|---|\n" + "".join(
        f"| {r['aa']} | {r['render_ms']} | {r['compile_s']} |\n" for r in rows
    )
    heads = ["scene", "camera", "size", "hit_pixels", "planes", "overflow", "drawn",
             "table_passes", "depth_agree", "color_agree", "passes"]  # fmt: skip
    text += (
        "\n## Agreement with the per-pixel 3-D DDA at every distance"
        " (% of pixels hit by either)\n\n"
        "Acceptance: depth within one voxel on >= 99 % and the same colour on >= 98 %.\n\n"
        + "| "
        + " | ".join(heads)
        + " |\n|"
        + "---|" * len(heads)
        + "\n"
        + "".join("| " + " | ".join(str(r[k]) for k in heads) + " |\n" for r in acc)
    )
    print(text)
    if args.out:
        from jaxgfx.io import save_json, save_png

        out = Path(args.out)
        save_png(out / "quality.png", np.clip(grid, 0, 1))
        save_json(
            out / "table.json", dict(machine=machine(), scene=name, rows=rows, acceptance=acc)
        )
        tmp = out / f".table.md.{os.getpid()}"
        tmp.write_text(text)
        os.replace(tmp, out / "table.md")
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
