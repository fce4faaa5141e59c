"""A vmapped batch of ``render_rle`` against a loop of single frames, at the flags users run.

``render_rle``'s docstring says that ``jax.vmap`` over cameras, lowered for the CPU, renders
the views one after another, bit-identical to a loop of eager or of jitted calls at XLA's
default flags.  This renders a voxelized dragon (``meshes/dragon_11k.ply`` of the shared data
at R = 128; a procedural tree without it) from 16 orbit cameras at 160x120: one jitted
``vmap`` over the stacked cameras, then each camera alone, called eagerly (the frame's own
compiled program) and through ``jax.jit(render_rle)``, and counts the frames whose depth or
colour differs from the batch's in any bit.  Run it without ``XLA_FLAGS`` for the claim
(the test suite's own code generation differs; its test of the claim compiles at the
user's).  ``--quick``: a small tree, 2 cameras of 64x48; on the CPU every way renders with
``RenderSettings(batching="frames")``, the rule the default ``"auto"`` lowers to there (the
same program, without tracing the accelerators' vectorized rule too).

Usage::

    python -m experiments.vmap_identity --out out/vmap_identity
    python -m experiments.vmap_identity --quick --out out/vmap_identity
"""

from __future__ import annotations

import argparse
import functools
import os
import sys

import jax
import numpy as np

from experiments.common import DATA, machine, markdown_table, write_table
from jaxgfx import raycast as RC
from jaxgfx.camera import orbit_cameras


def scene(quick: bool):
    """The voxels to render and their name."""
    path = DATA / "meshes" / "dragon_11k.ply"
    if path.is_file() and not quick:
        import trimesh

        m = trimesh.load(path, process=False)
        return RC.voxelize_mesh(m.vertices, m.faces, 128), "dragon R=128"
    res = 32 if quick else 128
    return RC.procedural_tree(res, key=jax.random.key(0)), f"tree R={res}"


def compare(rle, cams, n: int, settings=None) -> list[dict]:
    """Rows: for each way of rendering one camera at a time, the frames that differ."""
    frame = RC.render_rle
    if settings is not None:
        frame = functools.partial(RC.render_rle, settings=settings)
    batch = jax.jit(jax.vmap(frame, in_axes=(None, 0)))(rle, cams)
    jitted = jax.jit(frame)
    ways = {"eager calls": frame, "jitted calls": jitted}
    rows = []
    for way, render in ways.items():
        differ, depth_diff, hit = 0, 0.0, 0
        for k in range(n):
            one = render(rle, jax.tree_util.tree_map(lambda a, k=k: a[k], cams))
            d1, d2 = np.asarray(one.depth), np.asarray(batch.depth[k])
            same = np.array_equal(d1, d2) and np.array_equal(
                np.asarray(one.color), np.asarray(batch.color[k])
            )
            differ += not same
            both = np.isfinite(d1) & np.isfinite(d2)
            depth_diff = max(depth_diff, float(np.abs(d1[both] - d2[both]).max(initial=0.0)))
            hit += int(np.isfinite(d1).sum())
        rows.append(
            dict(
                loop=way,
                frames=n,
                frames_differing=differ,
                max_depth_diff=depth_diff,
                hit_pixels=hit,
                bit_identical="yes" if differ == 0 else "no",
            )
        )
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small tree, 2 cameras of 64x48")
    ap.add_argument("--out", default="out/vmap_identity", help="folder for the table")
    args = ap.parse_args(argv)
    vox, name = scene(args.quick)
    rle = RC.as_jax(RC.encode_rle(vox))
    X, Y, Z = rle.shape
    n, (w, h) = (2, (64, 48)) if args.quick else (16, (160, 120))  # quick: CI time
    cams = orbit_cameras([X / 2, Y * 0.4, Z / 2], 1.3 * max(X, Z), n=n, width=w, height=h)
    settings = None
    if args.quick and jax.default_backend() == "cpu":
        # Quick: the CPU's rule, which "auto" lowers to, without tracing the vectorized
        # rule of accelerators beside it (half of the run's trace time; CI time).
        settings = RC.RenderSettings(batching="frames")
    rows = compare(rle, cams, n, settings)
    flags = os.environ.get("XLA_FLAGS", "") or "none (XLA's defaults)"
    title = f"render_rle: vmap over {n} cameras against a loop, {name}, {w}x{h}"
    cols = ["loop", "frames", "frames_differing", "max_depth_diff", "hit_pixels", "bit_identical"]
    text = f"machine: {machine()}; XLA_FLAGS: {flags}\n\n" + markdown_table(rows, cols)
    print(f"# {title}\n\n{text}")
    write_table(args.out, title, text, dict(machine=machine(), flags=flags, rows=rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
