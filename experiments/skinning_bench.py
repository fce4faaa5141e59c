"""Table 5.2 / 5.3 of the thesis: skinning speed of LBS, DQS and spline skinning (+ styles).

A limb (closed cylinder, three chained splines, three influences per vertex as in the thesis's GPU
layout) is copied C times to about one million vertices; every copy has its own random pose (a
batch of characters, ``vmap`` over poses, the bind data shared as in the thesis).  Each method runs
pass 1 (its per-pose matrices) and pass 2 (per vertex) under one ``jit``.  LBS and DQS are driven by
the same skeleton (two bones per spline, :func:`jaxgfx.skin.bone_transforms`) with three bone
influences per vertex.  Compile time is reported apart; steady-state times are the medians of
interleaved repeats (all methods take turns, so machine load hits them alike) and the ratios are
measured in the same run.

Rows marked "per-vertex reference" run :func:`jaxgfx.skin.lbs_vertex` /
:func:`jaxgfx.skin.skin_vertex_sampled` vmapped (the layout before the structure-of-arrays kernels
of ``jaxgfx/_src/skin/kernels.py``).  The peer is LBS in numba ``prange`` on every core (same
data, positions and normals; skipped with the reason printed when numba is absent), and the
bound is a measured memory-copy rate: the bytes one vertex reads and writes (influences, bind
position and normal in, position and normal out) at the rate ``numpy.copyto`` moves them.
``--devices N`` re-runs the bench with N XLA host devices and adds rows with the batch of poses
sharded over them (``NamedSharding`` over a 1-D mesh, as :mod:`jaxgfx.sweep` does).

    python -m experiments.skinning_bench --quick --out out/skinning_bench
    python -m experiments.skinning_bench --quick --devices 2
"""

from __future__ import annotations

import argparse
import functools
import os
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec

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
from jaxgfx.sweep import device_mesh

SAMPLES = 32
_DEVICE_FLAG = "--xla_force_host_platform_device_count"


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
        j, w, v, n = data
        return skin.linear_blend_skinning(skin.bone_transforms(rig, pose), v, n, j, w)

    def lbs_reference(pose, data):
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

    def sampled_reference(pose, data):
        table, _ = skin.sample_spline_frames(rig, pose, SAMPLES)
        fn = lambda u, w, v, n: skin.skin_vertex_sampled(table, u, w, v, n)  # noqa: E731
        return jax.vmap(fn)(data.coord, data.weight, data.rest, data.rest_normal)

    def exact(pose, data):
        return skin.skin_exact(rig, pose, data)

    return {
        "LBS (SSD)": (lbs, lbs_data),
        "LBS, per-vertex reference": (lbs_reference, lbs_data),
        "DQS": (dqs, lbs_data),
        "spline, sampled (S=32)": (sampled("none"), (prepared, None)),
        "spline, sampled, per-vertex reference": (sampled_reference, prepared),
        "spline, exact": (exact, binding),
        "spline + radial": (sampled("radial"), (prepared, style)),
        "spline + rect": (sampled("rect"), (prepared, style)),
        "spline + radial + rect": (sampled("both"), (prepared, style)),
    }


# ----------------------------------------------------------------------------------------------
# the peer (numba prange LBS) and the bound (memory copy rate)
# ----------------------------------------------------------------------------------------------


def numba_lbs():
    """LBS of positions and normals in numba ``prange`` over (pose, vertex), or the reason why not.

    Same arithmetic as :func:`jaxgfx.skin.lbs_vertex`: blend the 12 coefficients (columns of
    ``[R | t]``), apply them to the bind position and normal, normalize the normal.
    """
    try:
        import numba
    except ImportError as e:  # optional extra: pip install jaxgfx[bench]
        return None, f"numba not installed ({e})"

    @numba.njit(parallel=True, cache=False)
    def lbs(tables, joints, weights, verts, normals, out_p, out_n):  # pragma: no cover
        copies, nv, ni = tables.shape[0], verts.shape[0], joints.shape[1]
        for k in numba.prange(copies * nv):
            c = k // nv
            v = k - c * nv
            m = np.zeros(12, np.float32)
            for i in range(ni):
                row = tables[c, joints[v, i]]
                wi = weights[v, i]
                for q in range(12):
                    m[q] += wi * row[q]
            x, y, z = verts[v, 0], verts[v, 1], verts[v, 2]
            out_p[c, v, 0] = m[0] * x + m[3] * y + m[6] * z + m[9]
            out_p[c, v, 1] = m[1] * x + m[4] * y + m[7] * z + m[10]
            out_p[c, v, 2] = m[2] * x + m[5] * y + m[8] * z + m[11]
            a, b, d = normals[v, 0], normals[v, 1], normals[v, 2]
            nx = m[0] * a + m[3] * b + m[6] * d
            ny = m[1] * a + m[4] * b + m[7] * d
            nz = m[2] * a + m[5] * b + m[8] * d
            s = 1.0 / np.sqrt(max(nx * nx + ny * ny + nz * nz, 1e-12))
            out_n[c, v, 0] = nx * s
            out_n[c, v, 1] = ny * s
            out_n[c, v, 2] = nz * s

    return lbs, f"numba {numba.__version__}, {numba.get_num_threads()} threads"


def copy_rate(nbytes: int, repeats: int) -> float:
    """Bytes per second ``numpy.copyto`` moves (read + write), median of ``repeats``.

    The array holds half of ``nbytes`` (at least 64 MiB, so the rate is DRAM's, not a cache's).
    """
    src = np.ones(max(nbytes, 1 << 27) // 8, np.float32)
    dst = np.empty_like(src)
    np.copyto(dst, src)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.copyto(dst, src)
        times.append(time.perf_counter() - t0)
    return 2 * src.nbytes / float(np.median(times))


def _rerun_with_devices(devices: int, argv) -> int:
    """Run the bench again in a fresh process with ``devices`` XLA host devices."""
    flags = os.environ.get("XLA_FLAGS", "")
    env = dict(os.environ, XLA_FLAGS=f"{flags} {_DEVICE_FLAG}={devices}".strip())
    cmd = [sys.executable, "-m", "experiments.skinning_bench", *argv]
    return subprocess.call(cmd, env=env)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="about 100 k vertices, few repeats")
    ap.add_argument("--out", default=None, help="folder for table.md / table.json")
    ap.add_argument("--vertices", type=int, default=None, help="total vertices (default 1 M)")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument(
        "--devices", type=int, default=1, help="XLA host devices to shard the batch over"
    )
    args = ap.parse_args(argv)
    if args.devices > 1 and _DEVICE_FLAG not in os.environ.get("XLA_FLAGS", ""):
        # the flag must be set before JAX starts its CPU backend: a fresh process
        return _rerun_with_devices(args.devices, sys.argv[1:] if argv is None else list(argv))

    total = args.vertices or (100_000 if args.quick else 1_000_000)
    repeats = args.repeats or (5 if args.quick else 9)
    print(machine())
    v, n, _ = cylinder(64, 196, radius=0.25, length=6.0)  # 12,546 vertices, like Table 5.2
    rig = limb_rig(3)
    binding = limb_binding(rig, v, n)
    ndev = min(args.devices, jax.device_count())
    copies = max(1, round(total / len(v)))
    copies = -(-copies // ndev) * ndev  # the batch splits evenly over the devices
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
        print(f"  compiled {name}: {compile_s[name]:.1f} s", flush=True)
    if ndev > 1:
        # every core: the batch of poses sharded over a 1-D mesh, bind data replicated
        mesh = device_mesh(jax.devices()[:ndev])
        shard = NamedSharding(mesh, PartitionSpec("batch"))
        poses_sharded = jax.device_put(poses, shard)
        for name in ("LBS (SSD)", "spline, sampled (S=32)"):
            fn, data = methods[name]
            f = jax.jit(
                lambda data, pose, fn=fn: jax.vmap(fn, in_axes=(0, None))(pose, data),
                out_shardings=shard,
            )
            key = f"{name}, sharded over {ndev} devices"
            t0 = time.perf_counter()
            jax.block_until_ready(f(data, poses_sharded))
            compile_s[key] = time.perf_counter() - t0
            compiled[key] = lambda _poses, f=f, d=data, p=poses_sharded: f(d, p)
    # the peer: numba prange LBS of the same data (pass 1 by JAX outside its timing)
    joints, weights, rest, rest_normal = (np.asarray(a) for a in methods["LBS (SSD)"][1])
    tables = jax.jit(jax.vmap(lambda p: skin.bone_transforms(rig, p)))(poses)
    tables = np.ascontiguousarray(np.swapaxes(np.asarray(tables), -1, -2).reshape(copies, -1, 12))
    nb_fn, nb_note = numba_lbs()
    print(f"peer: {nb_note}")
    nb_name = "LBS, numba prange (peer)"
    if nb_fn is not None:
        out_p = np.empty((copies, len(v), 3), np.float32)
        out_n = np.empty_like(out_p)
        nb_args = (tables, joints, weights, rest, rest_normal, out_p, out_n)
        t0 = time.perf_counter()
        nb_fn(*nb_args)
        compile_s[nb_name] = time.perf_counter() - t0
        compiled[nb_name] = lambda _poses, f=nb_fn, a=nb_args: f(*a)
        # the peer computes what the kernels compute
        ref_p, ref_n = compiled["LBS (SSD)"](poses)
        np.testing.assert_allclose(out_p, np.asarray(ref_p), atol=1e-4)
        np.testing.assert_allclose(out_n, np.asarray(ref_n), atol=1e-4)

    times: dict[str, list[float]] = {k: [] for k in compiled}
    for _ in range(repeats):
        for name, f in compiled.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f(poses))
            times[name].append(time.perf_counter() - t0)
    med = {k: float(np.median(t)) for k, t in times.items()}

    # the bound: what one vertex reads and writes, at the measured copy rate
    infl = joints.shape[1]
    bytes_per_vertex = infl * 8 + 2 * 12 + 2 * 12
    rate = copy_rate(nverts * bytes_per_vertex, repeats)
    bound_s = nverts * bytes_per_vertex / rate

    # accuracy of the fast path: sampled vs exact, in % of the limb radius
    pe = compiled["spline, exact"](poses)[0]
    ps = compiled["spline, sampled (S=32)"](poses)[0]
    dev = np.linalg.norm(np.asarray(pe - ps), axis=-1) / 0.25 * 100

    rows = []
    for name in compiled:
        rows.append(
            {
                "method": name,
                "compile_s": compile_s[name],
                "ms": med[name] * 1e3,
                "Mvertices_per_s": nverts / med[name] / 1e6,
                "ratio_to_LBS": med["LBS (SSD)"] / med[name],
                "ratio_to_numba": med[nb_name] / med[name] if nb_name in med else float("nan"),
                "fraction_of_memory_bound": bound_s / med[name],
            }
        )
    cols = [
        "method",
        "compile_s",
        "ms",
        "Mvertices_per_s",
        "ratio_to_LBS",
        "ratio_to_numba",
        "fraction_of_memory_bound",
    ]
    md = markdown_table(rows, cols)
    by_name = {r["method"]: r for r in rows}
    targets = {
        "sampled >= 0.9x LBS": by_name["spline, sampled (S=32)"]["ratio_to_LBS"] >= 0.9,
        "radial + rect >= 0.4x LBS": by_name["spline + radial + rect"]["ratio_to_LBS"] >= 0.4,
    }
    footer = (
        f"\n\n{nverts:,} vertices ({copies} posed copies), medians of {repeats} interleaved "
        f"repeats, compile excluded; machine: {machine()}; {ndev} XLA device(s).\n"
        f"Peer: {nb_note}.\nMemory bound: {bytes_per_vertex} bytes per vertex "
        f"({infl} influences) at the measured copy rate {rate / 1e9:.1f} GB/s (numpy.copyto, read "
        f"+ write) = {bound_s * 1e3:.2f} ms; fraction_of_memory_bound = bound / time.\n"
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
                "devices": ndev,
                "peer": nb_note,
                "copy_rate_bytes_per_s": rate,
                "memory_bound_ms": bound_s * 1e3,
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
