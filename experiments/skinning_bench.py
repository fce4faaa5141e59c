"""Table 5.2 / 5.3 of the thesis: skinning speed of LBS, DQS and spline skinning (+ styles).

A limb (closed cylinder, three chained splines, three influences per vertex as in the thesis's GPU
layout) is copied C times to about one million vertices; every copy has its own random pose (a
batch of characters, ``vmap`` over poses, the bind data shared as in the thesis).  Each method runs
pass 1 (its per-pose matrices) and pass 2 (per vertex) under one ``jit``.  LBS and DQS are driven by
the same skeleton (two bones per spline, :func:`jaxgfx.skin.bone_transforms`) with three bone
influences per vertex.  Compile time is reported apart; steady-state times are the best of
interleaved repeats (all methods take turns, so machine load hits them alike) and the ratio to LBS
is measured in the same run.

    python -m experiments.skinning_bench --quick --out out/skinning_bench
"""

from __future__ import annotations

import argparse
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

from experiments.common import (
    cylinder,
    limb_binding,
    limb_rig,
    machine,
    markdown_table,
    random_poses,
    write_table,
)
from jaxgfx import skin

SAMPLES = 32


def lbs_influences(binding, top: int = 3):
    """Three bone influences per vertex from the spline binding (the largest, renormalized)."""
    joints, weights = skin.bone_weights_from_binding(binding)
    order = jnp.argsort(-weights, axis=1)[:, :top]
    j = jnp.take_along_axis(joints, order, axis=1)
    w = jnp.take_along_axis(weights, order, axis=1)
    return j.astype(jnp.int32), w / jnp.sum(w, axis=1, keepdims=True)


def build_methods(rig, binding, style):
    """Each method maps (pose, data) -> (positions, normals); data are jit arguments."""
    prepared = skin.prepare_sampled(binding, SAMPLES)
    joints, weights = lbs_influences(binding)
    lbs_data = (joints, weights, binding.rest, binding.rest_normal)

    def lbs(pose, data):
        t = skin.bone_transforms(rig, pose)
        return jax.vmap(lambda j, w, v, n: skin.lbs_vertex(t, j, w, v, n))(*data)

    def dqs(pose, data):
        dual = skin.dual_quaternions(skin.bone_transforms(rig, pose))
        return jax.vmap(lambda j, w, v, n: skin.dqs_vertex(dual, j, w, v, n))(*data)

    def sampled(styles):
        def fn(pose, data):
            prep, st = data
            return skin.skin_sampled(rig, pose, prep, st, samples=SAMPLES, styles=styles)

        return fn

    def exact(pose, data):
        return skin.skin_exact(rig, pose, data)

    return {
        "LBS (SSD)": (lbs, lbs_data),
        "DQS": (dqs, lbs_data),
        "spline, sampled (S=32)": (sampled("none"), (prepared, None)),
        "spline, exact": (exact, binding),
        "spline + radial": (sampled("radial"), (prepared, style)),
        "spline + rect": (sampled("rect"), (prepared, style)),
        "spline + radial + rect": (sampled("both"), (prepared, style)),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="about 100 k vertices, few repeats")
    ap.add_argument("--out", default=None, help="folder for table.md / table.json")
    ap.add_argument("--vertices", type=int, default=None, help="total vertices (default 1 M)")
    ap.add_argument("--repeats", type=int, default=None)
    args = ap.parse_args(argv)

    total = args.vertices or (100_000 if args.quick else 1_000_000)
    repeats = args.repeats or (3 if args.quick else 7)
    print(machine())
    v, n, _ = cylinder(64, 196, radius=0.25, length=6.0)  # 12,546 vertices, like Table 5.2
    rig = limb_rig(3)
    binding = limb_binding(rig, v, n)
    copies = max(1, round(total / len(v)))
    poses = random_poses(rig, copies, jax.random.key(0))
    rng = np.random.default_rng(0)
    style = skin.make_style(
        0.8 + 0.4 * rng.random((3, 64, 32)), 0.8 + 0.4 * rng.random((3, 32)), hollow=0.0
    )
    methods = build_methods(rig, binding, style)
    nverts = copies * len(v)
    print(f"{copies} copies x {len(v)} vertices = {nverts:,} vertices, 3 splines / 6 bones each")

    compiled, compile_s = {}, {}
    for name, (fn, data) in methods.items():
        f = jax.jit(lambda data, pose, fn=fn: jax.vmap(fn, in_axes=(0, None))(pose, data))
        t0 = time.perf_counter()
        jax.block_until_ready(f(data, poses))
        compile_s[name] = time.perf_counter() - t0
        compiled[name] = functools.partial(f, data)
    best = {k: float("inf") for k in methods}
    for _ in range(repeats):
        for name, f in compiled.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f(poses))
            best[name] = min(best[name], time.perf_counter() - t0)

    # accuracy of the fast path: sampled vs exact, in % of the limb radius
    pe = compiled["spline, exact"](poses)[0]
    ps = compiled["spline, sampled (S=32)"](poses)[0]
    dev = np.linalg.norm(np.asarray(pe - ps), axis=-1) / 0.25 * 100

    rows = []
    for name in methods:
        rows.append(
            {
                "method": name,
                "compile_s": compile_s[name],
                "ms": best[name] * 1e3,
                "Mvertices_per_s": nverts / best[name] / 1e6,
                "ratio_to_LBS": best["LBS (SSD)"] / best[name],
            }
        )
    cols = ["method", "compile_s", "ms", "Mvertices_per_s", "ratio_to_LBS"]
    md = markdown_table(rows, cols)
    targets = {
        "sampled >= 0.9x LBS": rows[2]["ratio_to_LBS"] >= 0.9,
        "radial + rect >= 0.4x LBS": rows[6]["ratio_to_LBS"] >= 0.4,
    }
    footer = (
        f"\n\n{nverts:,} vertices ({copies} posed copies), best of {repeats} interleaved repeats; "
        f"machine: {machine()}.\n"
        f"Sampled vs exact spline skinning: mean {dev.mean():.4f} %, max {dev.max():.4f} % of the "
        f"limb radius.\nTargets: "
        + ", ".join(f"{k}: {'met' if ok else 'NOT met'}" for k, ok in targets.items())
        + "\nThesis (GeForce 7800): spline 0.92x SSD, spline + styles 0.35x SSD."
    )
    print(md + footer)
    if args.out:
        write_table(
            args.out,
            "Skinning speed (thesis Table 5.2 / 5.3)",
            md + footer,
            {
                "machine": machine(),
                "vertices": nverts,
                "copies": copies,
                "repeats": repeats,
                "rows": rows,
                "sampled_vs_exact_percent_radius": {
                    "mean": float(dev.mean()),
                    "max": float(dev.max()),
                },
                "targets_met": targets,
            },
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
