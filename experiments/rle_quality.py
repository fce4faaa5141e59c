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

Usage::

    python -m experiments.rle_quality --quick --out out/rle_quality
"""

from __future__ import annotations

import argparse
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    w, h = (96, 72) if args.quick else (256, 192)
    res = 48 if args.quick else 128
    if (DATA / "meshes" / "bun_zipper_res2.ply").is_file():
        import trimesh

        m = trimesh.load(DATA / "meshes" / "bun_zipper_res2.ply", process=False)
        vox = RC.voxelize_mesh(m.vertices, m.faces, res)
        name = f"bunny R={res}"
    else:
        vox = RC.procedural_tree(res, key=jax.random.key(0))
        name = f"tree R={res}"
    rle = RC.as_jax(RC.encode_rle(vox))
    X, Y, Z = vox.shape
    c = np.array([X / 2, Y / 2, Z / 2])
    eye = c + np.array([0.55 * X, 0.2 * Y, 0.6 * Z])
    render = jax.jit(RC.render_rle)
    shaded = jax.jit(
        lambda cam, col, dep: post.shade(
            col,
            post.screen_space_normals(cam, dep, key=jax.random.key(1)),
            post.ambient_occlusion(dep, key=jax.random.key(2)),
        )
    )
    tiles, rows = [], []
    for fx, fy in ((1, 1), (2, 1), (2, 2)):
        cam = supersampled(look_at(eye, c, 50, w, h), (fx, fy))
        t0 = time.perf_counter()
        out = jax.block_until_ready(render(rle, cam))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        out = jax.block_until_ready(render(rle, cam))
        steady = time.perf_counter() - t0
        col, dep = post.antialias(out.color, out.depth, (fx, fy))
        sm, sdep = post.smooth(col, dep)
        cam1 = look_at(eye, c, 50, w, h)
        sh = shaded(cam1, sm, sdep)
        tiles.append([np.asarray(col), np.asarray(sm), np.asarray(sh)])
        rows.append(dict(aa=f"{fx}x{fy}", render_ms=round(1e3 * steady, 1),
                         compile_s=round(first - steady, 1)))  # fmt: skip
    grid = np.concatenate([np.concatenate(t, axis=0) for t in tiles], axis=1)
    text = f"Machine: {machine()}; scene {name}; frame {w}x{h}\n\n| aa | render_ms | compile_s |\n"
    text += "|---|---|---|\n" + "".join(
        f"| {r['aa']} | {r['render_ms']} | {r['compile_s']} |\n" for r in rows
    )
    print(text)
    if args.out:
        from jaxgfx.io import save_json, save_png

        out = Path(args.out)
        save_png(out / "quality.png", np.clip(grid, 0, 1))
        save_json(out / "table.json", dict(machine=machine(), scene=name, rows=rows))
        tmp = out / f".table.md.{os.getpid()}"
        tmp.write_text(text)
        os.replace(tmp, out / "table.md")
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
