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
of ``jaxgfx/_src/skin/kernels.py``).  The issue's LBS target is measured on a second setting,
the "crowd": the same batch of meshes with 64 random bones per character and 4 influences per
vertex (:func:`crowd_data`).  The peer is LBS in numba ``prange`` on every core (same data,
positions and normals, both settings; skipped with the reason printed when numba is absent), and
the bound is a measured memory-copy rate: the bytes one vertex reads and writes (influences, bind
position and normal in, position and normal out) at the rate ``numpy.copyto`` moves them.
By default the bench runs with one XLA host device per core (re-executing itself with
``--xla_force_host_platform_device_count``; ``--devices 1`` for one) and adds rows with the batch
of poses split over them by :func:`jaxgfx.sweep.sharded_vmap` (bind data replicated once; each
device loops over chunks of ``CHUNK`` poses, which keeps the bone table in cache), so both sides
use every core.  ``--quick`` (the CI smoke test) times only the rows the targets
need.

    python -m experiments.skinning_bench --quick --out out/skinning_bench
    python -m experiments.skinning_bench --devices 1  # one core
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
from jaxgfx.sweep import shard_batch, sharded_vmap

SAMPLES = 32
_DEVICE_FLAG = "--xla_force_host_platform_device_count"
CROWD_BONES = 64
LIMB = "limb: 3 influences, 6 bones"
CROWD = f"crowd: 4 influences, {CROWD_BONES} bones"
ONE = f"one mesh: 4 influences, {CROWD_BONES} bones"
PEER = "LBS, numba prange (peer)"
ROW_GATHER = "LBS design: (V, I, 12) row gather + contraction"
ONE_HOT_BLOCK = 16384  # vertices per step of the one-hot design (its (block, J) weights in cache)
ONE_HOT = f"LBS design: one-hot weights @ bone rows, blocks of {ONE_HOT_BLOCK}"
_LBS_ROW = {LIMB: "LBS (SSD)", CROWD: "LBS", ONE: "LBS"}
QUICK_METHODS = ("LBS (SSD)", "spline, sampled (S=32)", "spline + radial + rect")
CHUNK = 8  # poses per step of each device's loop (sharded_vmap's chunk)
SUBROWS = 16  # sub-rows per sample of the sampled table (skin_sampled(..., subrows=))
SUBROWS_ROW = f"spline, sampled (S=32, {SUBROWS} sub-rows)"
STYLES_SUBROWS_ROW = f"spline + radial + rect ({SUBROWS} sub-rows)"
SHARDED_METHODS = (
    "LBS (SSD)",
    "spline, sampled (S=32)",
    SUBROWS_ROW,
    "spline + radial + rect",
    STYLES_SUBROWS_ROW,
)


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

    def sampled(styles, subrows=None):
        def fn(pose, data):
            prep, st = data
            return skin.skin_sampled(
                rig, pose, prep, st, samples=SAMPLES, styles=styles, subrows=subrows
            )

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
        SUBROWS_ROW: (sampled("none", SUBROWS), (prepared, None)),
        "spline, sampled, per-vertex reference": (sampled_reference, prepared),
        "spline, exact": (exact, binding),
        "spline + radial": (sampled("radial"), (prepared, style)),
        "spline + rect": (sampled("rect"), (prepared, style)),
        "spline + radial + rect": (sampled("both"), (prepared, style)),
        STYLES_SUBROWS_ROW: (sampled("both", SUBROWS), (prepared, style)),
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


# other designs of one-mesh LBS, measured against the kernel (``skin.linear_blend_skinning``,
# scalar gathers of coefficient columns in structure-of-arrays layout)
# ----------------------------------------------------------------------------------------------


def _bone_rows(transforms) -> jax.Array:
    """(J, 3, 4) -> (J, 12) rows, columns of ``[R | t]`` (as numba's table)."""
    return jnp.swapaxes(transforms[:, :3, :], -1, -2).reshape(transforms.shape[0], 12)


def _apply_rows(m, vertices, normals):
    """Positions and unit normals from blended (V, 12) rows (array-of-structures layout)."""
    r = m[:, :9].reshape(-1, 3, 3)
    pos = jnp.einsum("vk,vkc->vc", vertices, r) + m[:, 9:]
    nrm = jnp.einsum("vk,vkc->vc", normals, r)
    return pos, nrm * jax.lax.rsqrt(jnp.maximum(jnp.sum(nrm * nrm, -1, keepdims=True), 1e-12))


def lbs_row_gather(transforms, vertices, normals, joints, weights):
    """LBS as the per-vertex formula vectorizes: gather (V, I, 12) bone rows, contract."""
    rows = _bone_rows(transforms)[joints]  # (V, I, 12)
    return _apply_rows(jnp.einsum("vi,vic->vc", weights, rows), vertices, normals)


def lbs_one_hot(transforms, vertices, normals, joints, weights):
    """LBS as dense matrix products: per block of vertices, (block, J) weights @ (J, 12) rows.

    No per-vertex gather of the bone table: each vertex's dense weight row is built by
    comparing its bone indices with every bone, and the blend is a matrix product.
    """
    rows = _bone_rows(transforms)
    bones = jnp.arange(rows.shape[0], dtype=joints.dtype)
    nv = vertices.shape[0]
    steps = -(-nv // ONE_HOT_BLOCK)

    def blocks(x):  # (V, ...) -> (steps, ONE_HOT_BLOCK, ...), zero rows (weight 0) at the end
        x = jnp.pad(x, [(0, steps * ONE_HOT_BLOCK - nv)] + [(0, 0)] * (x.ndim - 1))
        return x.reshape(steps, ONE_HOT_BLOCK, *x.shape[1:])

    def block(a):
        v, n, j, w = a
        dense = jnp.sum(w[:, :, None] * (j[:, :, None] == bones), axis=1)  # (block, J)
        return _apply_rows(dense @ rows, v, n)

    pos, nrm = jax.lax.map(block, tuple(blocks(x) for x in (vertices, normals, joints, weights)))
    return pos.reshape(-1, 3)[:nv], nrm.reshape(-1, 3)[:nv]


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


def crowd_data(copies: int, nv: int, key, *, bones: int = CROWD_BONES, influences: int = 4):
    """A crowd for the LBS-vs-numba target: ``copies`` characters of ``nv`` vertices each.

    Every character has its own ``bones`` random rigid transforms (a rotation about a random axis
    and a translation); the bind data (random bones and weights per vertex) is shared.
    """
    k1, k2, k3, k4 = jax.random.split(key, 4)
    rot = jax.vmap(jax.vmap(skin.axis_angle_to_matrix))(jax.random.normal(k1, (copies, bones, 3)))
    trans = jax.random.normal(k2, (copies, bones, 3, 1))
    transforms = jnp.concatenate([rot, trans], axis=-1)  # (copies, bones, 3, 4)
    joints = jax.random.randint(k3, (nv, influences), 0, bones, jnp.int32)
    w = jax.random.uniform(k4, (nv, influences), minval=0.05, maxval=1.0)
    return transforms, joints, w / jnp.sum(w, axis=1, keepdims=True)


def _chunked(rig, method, name, poses, devices):
    """``method`` over ``poses`` split over ``devices``, each looping over chunks of CHUNK poses.

    For the sampled methods only pass 2 runs in the chunk loop: pass 1 (about 45 small ops per
    pose) runs vmapped over each device's whole shard once, as one set of ops.
    """
    fn, data = method
    styles, subrows = {
        "spline, sampled (S=32)": ("none", None),
        SUBROWS_ROW: ("none", SUBROWS),
        "spline + radial": ("radial", None),
        "spline + rect": ("rect", None),
        "spline + radial + rect": ("both", None),
        STYLES_SUBROWS_ROW: ("both", SUBROWS),
    }.get(name, (None, None))
    if styles is None:
        sm = sharded_vmap(fn, (0, None), devices, chunk=CHUNK)
        a = (sm.split(poses), sm.replicate(data))
        return lambda: sm(*a)
    pass1 = sharded_vmap(lambda p: skin.sample_spline_frames(rig, p, SAMPLES), (0,), devices)
    pass2 = sharded_vmap(
        lambda tab, sty_tab, d: skin.skin_sampled_tables(
            tab, sty_tab, d[0], d[1], samples=SAMPLES, styles=styles, subrows=subrows
        ),
        (0, 0, None),
        devices,
        chunk=CHUNK,
    )
    split, shared = pass1.split(poses), pass2.replicate(data)
    return lambda: pass2(*pass1(split), shared)


def _rerun_with_devices(devices: int, argv) -> int:
    """Run the bench again in a fresh process with ``devices`` XLA host devices."""
    flags = os.environ.get("XLA_FLAGS", "")
    env = dict(os.environ, XLA_FLAGS=f"{flags} {_DEVICE_FLAG}={devices}".strip())
    cmd = [sys.executable, "-m", "experiments.skinning_bench", *argv]
    return subprocess.call(cmd, env=env)


def _tables(transforms) -> np.ndarray:
    """(copies, J, 3, 4) -> numba's (copies, J, 12) rows, columns of ``[R | t]``."""
    return np.ascontiguousarray(jax.vmap(_bone_rows)(jnp.asarray(transforms)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="about 100 k vertices, the target rows only"
    )
    ap.add_argument("--out", default=None, help="folder for table.md / table.json")
    ap.add_argument("--vertices", type=int, default=None, help="total vertices (default 1 M)")
    ap.add_argument("--repeats", type=int, default=None, help="interleaved timing rounds")
    ap.add_argument(
        "--devices",
        type=int,
        default=os.cpu_count() or 1,
        help="XLA host devices to shard the batch over (default: one per core, as numba's threads)",
    )
    args = ap.parse_args(argv)
    if args.devices < 1:
        ap.error(f"--devices must be >= 1, got {args.devices}")
    if args.devices > 1 and _DEVICE_FLAG not in os.environ.get("XLA_FLAGS", ""):
        # the flag must be set before JAX starts its CPU backend: a fresh process
        return _rerun_with_devices(args.devices, sys.argv[1:] if argv is None else list(argv))

    # As the jaxgfx command and the other benchmarks do: XLA:CPU's calls reuse freed memory
    # instead of touching fresh pages every call (numba writes into preallocated outputs).
    import jaxgfx

    jaxgfx.keep_freed_memory()
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
    every_method = build_methods(rig, binding, style)
    methods = every_method
    if args.quick:  # the CI smoke test: the rows the targets need
        methods = {k: methods[k] for k in QUICK_METHODS}
    nverts = copies * len(v)
    print(f"{copies} copies x {len(v)} vertices = {nverts:,} vertices, 3 splines / 6 bones each")

    # every timed row: (setting, method) -> callable of no arguments
    compiled, compile_s = {}, {}

    def add(name, where, fn):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        compile_s[where, name] = time.perf_counter() - t0
        compiled[where, name] = fn
        print(f"  compiled {name} ({where}): {compile_s[where, name]:.1f} s", flush=True)

    for name, (fn, data) in methods.items():
        f = jax.jit(lambda data, pose, fn=fn: jax.vmap(fn, in_axes=(0, None))(pose, data))
        add(name, LIMB, functools.partial(f, data, poses))
    # in chunks of CHUNK poses, on one device (like for like with the chunked LBS) and on every
    # device: the batch of poses split over the devices, bind data replicated once
    for d in () if args.quick else sorted({1, ndev}):
        for name in SHARDED_METHODS:
            run = _chunked(rig, every_method[name], name, poses, jax.devices()[:d])
            add(f"{name}, {d} device(s), chunks of {CHUNK}", LIMB, run)

    # the crowd (64 bones, 4 influences): LBS on one device, on every device, and numba
    transforms, cj, cw = crowd_data(copies, len(v), jax.random.key(1))
    v, n = v.astype(np.float32), n.astype(np.float32)
    crowd_mesh = (jnp.asarray(v), jnp.asarray(n), cj, cw)
    lbs_b = jax.jit(jax.vmap(skin.linear_blend_skinning, in_axes=(0, None, None, None, None)))
    add("LBS", CROWD, lambda: lbs_b(transforms, *crowd_mesh))
    for d in () if args.quick else sorted({1, ndev}):
        # the batch in chunks of CHUNK poses per step (the bone table stays in cache), per device
        sm = sharded_vmap(
            skin.linear_blend_skinning, (0, None, None, None, None), jax.devices()[:d], chunk=CHUNK
        )
        a = (sm.split(transforms), *sm.replicate(crowd_mesh))
        add(f"LBS, {d} device(s), chunks of {CHUNK}", CROWD, lambda sm=sm, a=a: sm(*a))

    # As users call the kernels: one large mesh (one pose of every vertex) and the crowd's
    # poses under jit(vmap), each on one device and placed over every device by shard_batch.
    t_one, one_j, one_w = crowd_data(1, nverts, jax.random.key(2))
    t_one = t_one[0]
    one_v = rng.normal(size=(nverts, 3)).astype(np.float32)
    one_n = one_v / np.linalg.norm(one_v, axis=1, keepdims=True)
    one_mesh = (one_v, one_n, one_j, one_w)
    lbs_1, dqs_1 = jax.jit(skin.linear_blend_skinning), jax.jit(skin.dual_quaternion_skinning)
    dqs_b = jax.jit(jax.vmap(skin.dual_quaternion_skinning, in_axes=(0, None, None, None, None)))
    add("LBS", ONE, lambda: lbs_1(t_one, *one_mesh))
    add("DQS", ONE, lambda: dqs_1(t_one, *one_mesh))
    if not args.quick:  # the designs the kernel was measured against (design notes)
        for name, design in (
            (ROW_GATHER, lbs_row_gather),
            (ONE_HOT, lbs_one_hot),
        ):
            add(name, ONE, functools.partial(jax.jit(design), t_one, *one_mesh))
            for got, want in zip(compiled[ONE, name](), compiled[ONE, "LBS"](), strict=True):
                np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-4)
    if not args.quick:  # the smoke test compiles the target rows only
        add("DQS", CROWD, lambda: dqs_b(transforms, *crowd_mesh))
    if ndev > 1:
        spread_mesh = shard_batch(one_mesh)
        spread_poses = shard_batch(transforms)
        add(f"LBS, vertices over {ndev} devices", ONE, lambda: lbs_1(t_one, *spread_mesh))
        add(f"DQS, vertices over {ndev} devices", ONE, lambda: dqs_1(t_one, *spread_mesh))
        over = f"poses over {ndev} devices"
        add(f"LBS, vmap, {over}", CROWD, lambda: lbs_b(spread_poses, *crowd_mesh))
        if not args.quick:
            add(f"DQS, vmap, {over}", CROWD, lambda: dqs_b(spread_poses, *crowd_mesh))

    # the peer: numba prange LBS of the same data (pass 1 by JAX outside its timing)
    nb_fn, nb_note = numba_lbs()
    print(f"peer: {nb_note}")
    limb_tables = jax.jit(jax.vmap(lambda p: skin.bone_transforms(rig, p)))(poses)
    peer_data = {
        LIMB: (_tables(limb_tables), *(np.asarray(a) for a in methods["LBS (SSD)"][1])),
        CROWD: (_tables(transforms), np.asarray(cj), np.asarray(cw), v, n),
        ONE: (_tables(t_one[None]), np.asarray(one_j), np.asarray(one_w), one_v, one_n),
    }
    if nb_fn is not None:
        for where, (tables, joints, weights, rest, rest_normal) in peer_data.items():
            out_p = np.empty((len(tables), len(rest), 3), np.float32)
            out_n = np.empty_like(out_p)
            nb_args = (tables, joints, weights, rest, rest_normal, out_p, out_n)
            add(PEER, where, lambda f=nb_fn, a=nb_args: f(*a))
            # the peer computes what the kernels compute
            ref_p, ref_n = compiled[where, _LBS_ROW[where]]()
            np.testing.assert_allclose(out_p.reshape(np.shape(ref_p)), np.asarray(ref_p), atol=1e-4)
            np.testing.assert_allclose(out_n.reshape(np.shape(ref_n)), np.asarray(ref_n), atol=1e-4)

    times: dict[tuple[str, str], list[float]] = {k: [] for k in compiled}
    for _ in range(repeats):
        for name, f in compiled.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f())
            times[name].append(time.perf_counter() - t0)
    # ratios from the best of the interleaved rounds: on a shared box (load 5-10 here) the
    # fastest round is the one least disturbed; medians are reported beside them
    med = {k: float(np.median(t)) for k, t in times.items()}
    best = {k: float(np.min(t)) for k, t in times.items()}

    # the bound: what one vertex reads and writes, at the measured copy rate
    rate = copy_rate(nverts * 80, repeats)
    bytes_per_vertex = {
        LIMB: peer_data[LIMB][1].shape[1] * 8 + 2 * 12 + 2 * 12,
        CROWD: cj.shape[1] * 8 + 2 * 12 + 2 * 12,
        ONE: cj.shape[1] * 8 + 2 * 12 + 2 * 12,
    }
    bound_s = {k: nverts * b / rate for k, b in bytes_per_vertex.items()}

    dev_note = "skipped in --quick"
    if (LIMB, "spline, exact") in compiled:
        # accuracy of the fast path: sampled vs exact, in % of the limb radius
        pe = compiled[LIMB, "spline, exact"]()[0]
        notes = []
        for name in ("spline, sampled (S=32)", SUBROWS_ROW):
            ps = compiled[LIMB, name]()[0]
            dev = np.linalg.norm(np.asarray(pe - ps), axis=-1) / 0.25 * 100
            notes.append(f"{name}: mean {dev.mean():.4f} %, max {dev.max():.4f} %")
        dev_note = "; ".join(notes) + " of the limb radius"

    rows = []
    for key in sorted(compiled, key=lambda k: (k[0] != LIMB, k[0] != CROWD)):
        where, name = key
        peer = (where, PEER)
        rows.append(
            {
                "setting": where,
                "method": name,
                "compile_s": compile_s[key],
                "best_ms": best[key] * 1e3,
                "median_ms": med[key] * 1e3,
                "Mvertices_per_s": nverts / best[key] / 1e6,
                "ratio_to_LBS": best[where, _LBS_ROW[where]] / best[key],
                "ratio_to_numba": best[peer] / best[key] if peer in best else float("nan"),
                "fraction_of_memory_bound": bound_s[where] / best[key],
            }
        )
    cols = list(rows[0])
    md = markdown_table(rows, cols)
    by = {(r["setting"], r["method"]): r for r in rows}
    best_crowd = by.get((CROWD, f"LBS, {ndev} device(s), chunks of {CHUNK}"))
    spread = f"over {ndev} devices" if ndev > 1 else None

    def numba_ratio(where, name):
        row = by.get((where, name))
        return row["ratio_to_numba"] if row else float("nan")

    one_name = f"LBS, vertices {spread}" if spread else "LBS"
    vmap_name = f"LBS, vmap, poses {spread}" if spread else "LBS"
    dqs_ratio = by[(ONE, "LBS")]["best_ms"] / by[(ONE, "DQS")]["best_ms"]
    targets = {
        f"one mesh, {one_name} >= 1x numba ({numba_ratio(ONE, one_name):.2f}x)": (
            numba_ratio(ONE, one_name) >= 1.0
        ),
        f"crowd, {vmap_name} >= 1x numba ({numba_ratio(CROWD, vmap_name):.2f}x)": (
            numba_ratio(CROWD, vmap_name) >= 1.0
        ),
        f"one mesh, DQS >= 0.5x LBS ({dqs_ratio:.2f}x)": dqs_ratio >= 0.5,
        f"LBS ({CROWD}, {ndev} device(s), chunks) >= 1x numba": (
            best_crowd is not None and best_crowd["ratio_to_numba"] >= 1.0
        ),
        "sampled >= 0.9x LBS": by[(LIMB, "spline, sampled (S=32)")]["ratio_to_LBS"] >= 0.9,
        "radial + rect >= 0.4x LBS": by[(LIMB, "spline + radial + rect")]["ratio_to_LBS"] >= 0.4,
    }
    for d in () if args.quick else sorted({1, ndev}):
        # the same ratios in chunks of CHUNK poses (each against the chunked LBS row, like for like)
        tag = f", {d} device(s), chunks of {CHUNK}"
        lbs_all = by[(LIMB, "LBS (SSD)" + tag)]["best_ms"]
        for key, name, low in (
            ("sampled", "spline, sampled (S=32)", 0.9),
            (f"sampled, {SUBROWS} sub-rows", SUBROWS_ROW, 0.9),
            ("radial + rect", "spline + radial + rect", 0.4),
            (f"radial + rect, {SUBROWS} sub-rows", STYLES_SUBROWS_ROW, 0.4),
        ):
            ratio = lbs_all / by[(LIMB, name + tag)]["best_ms"]
            targets[f"{key} >= {low}x LBS, {d} device(s), chunked ({ratio:.2f}x)"] = ratio >= low
    footer = (
        f"\n\n{nverts:,} vertices ({copies} posed copies of {len(v):,}) per row, best and median "
        f"of {repeats} interleaved rounds, compile excluded; M vertices/s and ratios from the "
        f"best; ratio_to_LBS and ratio_to_numba "
        f"against the 1-device LBS row and the numba row of the same setting; machine: "
        f"{machine()}; {ndev} XLA device(s).\nPeer: {nb_note}.\nMemory bound: "
        + ", ".join(
            f"{k}: {b} bytes per vertex = {bound_s[k] * 1e3:.2f} ms"
            for k, b in bytes_per_vertex.items()
        )
        + f", at the measured copy rate {rate / 1e9:.1f} GB/s (numpy.copyto, read + write); "
        f"fraction_of_memory_bound = bound / time.\nSampled vs exact spline skinning: "
        f"{dev_note}.\nTargets: "
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
                "memory_bound_ms": {k: b * 1e3 for k, b in bound_s.items()},
                "rows": rows,
                "sampled_vs_exact": dev_note,
                "targets_met": targets,
            },
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
