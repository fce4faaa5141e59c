"""Rasterizer speed beside the CPU renderers a user would pick instead, same run, same pixels.

Two tables, both with depth agreement (the share of pixels where the two depth images agree:
both empty, or both hit within ``RTOL`` relative camera z), so every ratio compares the same
work:

1. One frame: the Stanford bunny (69 k triangles, from ../shared/data, or an icosphere when
   the data is absent) and a procedural ~718 k-triangle heightfield (thesis Table 3.1 scale),
   at 512x384 and 1024x768: ``jax.jit(rasterize)`` on one device (one core) and, with
   several host devices, ``rasterize(devices=D)`` (the frame's faces split over all D;
   ``split_equal``: bit-identical to one device) against open3d's ``RaycastingScene``
   (Embree, every core), Mesa llvmpipe (OpenGL through a moderngl EGL context, depth read
   back inside the timing) and trimesh's ray caster on embreex (one thread); and the cost of
   a gradient through the same frame (no peer): ``jax.grad`` of the summed colour (the
   vertex positions as attributes) w.r.t. the vertices, and of the summed finite depth
   w.r.t. the camera (``grad_vertices_ms``, ``grad_camera_ms``).
2. Batches: the bunny at 512x384 from 1, 8, 32 and 128 orbit cameras, depth only and
   colour + depth, frames per second of a Python loop over the single-camera jit,
   ``jax.jit(jax.vmap(rasterize))`` with the batch on one device (``vmap``) and with the batch
   sharded over one host device per core (``vmap_sharded``: ``jax.device_put(cams,
   NamedSharding(mesh, P("batch")))``, the documented way to use every core), and the peers
   (open3d casts the whole batch in one call, llvmpipe draws and reads back one frame after
   another); with the process CPU time per frame of the vmap and loop rows.  The process has
   one host device per core (``jax_num_cpu_devices``, set before JAX starts; the machine
   line names the devices).
3. With ``--stripes`` (instead of both): the bunny's frame (colour and depth) at 512x384 and
   1024x768 with its shading in one pass and in stripes of rows (``STRIPE_RULES``; XLA:CPU's
   rule is stripes of at most 2^18 pixels), wall and process CPU time, and whether the
   frames agree.  ``--fresh-memory`` leaves out ``jaxgfx.keep_freed_memory()``, so that
   XLA:CPU's large buffers come fresh from the OS every call, as in a script that does not
   call it.

Timing: compile excluded; the methods are timed in interleaved rounds (each round runs every
method once) and the best round is reported, so load from other processes hits all alike.
The machine line gives the load.  Peer set-up (BVH, vertex buffers, each camera's rays or
matrix) is outside the timing; see ``experiments/_raster_peers.py``.  Peers come with
``pip install '.[bench]'`` and the OS packages ``libegl1 libgl1-mesa-dri libegl-mesa0``
(llvmpipe) and ``libusb-1.0-0`` (open3d); a missing peer is skipped with the printed reason.

    python -m experiments.bench_raster [--quick] [--out DIR] [--stripes [--fresh-memory]]

writes ``table.md``/``table.json`` (both tables), ``bench_raster.png`` (the figure) and depth
images (``*_depth.png``: jaxgfx; ``*_llvmpipe_depth.png``: the GL peer, for a look).
"""

from __future__ import annotations

import argparse
import functools
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import trimesh

from experiments.common import DATA, best_rounds, machine, markdown_table, write_table

RTOL = 1e-3  # depth agreement: |z_jaxgfx - z_peer| <= RTOL * z (float32 GL depth: ~3e-5)
BATCHES = (1, 8, 32, 128)


def heightfield(n: int) -> trimesh.Trimesh:
    """An n x n-vertex rolling terrain, 2 (n-1)^2 triangles, deterministic."""
    from jaxgfx.scene import grid_faces

    x, z = np.meshgrid(np.linspace(-50, 50, n), np.linspace(0, 100, n))
    y = 3 * np.sin(x / 5) * np.cos(z / 7) + 1.5 * np.sin(x / 1.7 + z / 2.3)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    return trimesh.Trimesh(v, grid_faces(n), process=False)


def bunny(quick: bool = False) -> tuple[str, trimesh.Trimesh]:
    """The Stanford bunny (its 3.8k-triangle version with ``quick``) or an icosphere."""
    from jaxgfx.io import load_mesh

    path = DATA / "meshes" / ("bun_zipper_res3.ply" if quick else "bun_zipper.ply")
    if path.exists():
        m = load_mesh(path)
        return f"bunny (Stanford, {len(m.faces) / 1000:.0f}k)", m
    ico = trimesh.creation.icosphere(subdivisions=4 if quick else 6)
    return "icosphere (bunny data absent)", ico


def scenes(quick: bool):
    """(name, tag, mesh, view) for the one-frame table."""
    name, m = bunny(quick)
    lo, hi = m.bounds
    c = 0.5 * (lo + hi)
    r = 0.5 * float(np.linalg.norm(hi - lo))
    view = dict(eye=c + r * np.array([0.4, 0.4, 2.4]), target=c, near=0.01 * r, far=100 * r)
    yield name, "bunny", m, view
    if quick:
        return
    t = heightfield(600)
    yield (
        f"terrain heightfield ({len(t.faces) // 1000}k)",
        "terrain",
        t,
        dict(
            eye=np.array([0.0, 12.0, -5.0]), target=np.array([0.0, 0.0, 40.0]), near=0.1, far=500.0
        ),
    )


def agreement(ours: np.ndarray, ref: np.ndarray) -> float:
    """Share of pixels where both depth images are empty, or both hit within ``RTOL``."""
    ours, ref = np.asarray(ours, np.float64), np.asarray(ref, np.float64)
    a, b = np.isfinite(ours), np.isfinite(ref)
    both = a & b
    ours, ref = np.where(both, ours, 0.0), np.where(both, ref, 0.0)
    close = np.abs(ours - ref) <= RTOL * np.abs(ours)
    return float(np.mean((~a & ~b) | (both & close)))


def one_frame_table(args, peers_for, raster, split=None) -> list[dict]:
    """``split``: ``rasterize`` with the frame's faces over every host device (or None)."""
    from jaxgfx.camera import look_at
    from jaxgfx.compose import depth_image
    from jaxgfx.io import save_png
    from jaxgfx.raster import rasterize

    def colour_sum(vertices, cam, faces):
        return jnp.sum(rasterize(cam, vertices, faces, vertices).color)

    def depth_sum(cam, vertices, faces):
        depth = rasterize(cam, vertices, faces).depth
        return jnp.sum(jnp.where(jnp.isfinite(depth), depth, 0.0))

    grad_vertices, grad_camera = jax.jit(jax.grad(colour_sum)), jax.jit(jax.grad(depth_sum))
    sizes = [(128, 96)] if args.quick else [(512, 384), (1024, 768)]
    rows = []
    for name, tag, mesh, view in scenes(args.quick):
        v = np.asarray(mesh.vertices, np.float32)
        f = np.asarray(mesh.faces, np.int32)
        peers = peers_for(v, f)
        for w, h in sizes:
            cam = look_at(view["eye"], view["target"], 50.0, w, h, view["near"], view["far"])
            t0 = time.perf_counter()
            jax.block_until_ready(raster(cam, v, f, v))
            compile_s = time.perf_counter() - t0
            states = {p.name: p.prepare([cam]) for p in peers}
            methods = {
                "jaxgfx": lambda cam=cam, v=v, f=f: jax.block_until_ready(raster(cam, v, f, v))
            }
            if split is not None:  # the same frame, its faces split over every host device
                jax.block_until_ready(split(cam, v, f, v))
                methods["jaxgfx_split"] = lambda cam=cam, v=v, f=f: jax.block_until_ready(
                    split(cam, v, f, v)
                )
            methods["grad_vertices"] = lambda cam=cam, v=v, f=f: jax.block_until_ready(
                grad_vertices(v, cam, f)
            )
            methods["grad_camera"] = lambda cam=cam, v=v, f=f: jax.block_until_ready(
                grad_camera(cam, v, f)
            )
            methods["grad_vertices"]()  # compile
            methods["grad_camera"]()
            for p in peers:
                methods[p.name] = lambda p=p, s=states[p.name]: p.run(s)
                p.run(states[p.name])  # warm-up (first GL draw compiles shaders, ...)
            best, outs = best_rounds(methods, args.rounds)
            depth = np.asarray(outs["jaxgfx"].depth)
            row = dict(
                mesh=name,
                triangles=len(f),
                size=f"{w}x{h}",
                compile_s=compile_s - best["jaxgfx"],
                jaxgfx_ms=best["jaxgfx"] * 1e3,
                coverage=f"{np.isfinite(depth).mean() * 100:.1f}%",
                grad_vertices_ms=best["grad_vertices"] * 1e3,
                grad_camera_ms=best["grad_camera"] * 1e3,
            )
            for p in peers:
                row[f"{p.name}_ms"] = best[p.name] * 1e3
                row[f"agree_{p.name}"] = f"{agreement(depth, outs[p.name][0]) * 100:.3f}%"
            if split is not None:
                row["jaxgfx_split_ms"] = best["jaxgfx_split"] * 1e3
                row["split_equal"] = all(
                    np.array_equal(np.asarray(a), np.asarray(b))
                    for a, b in zip(outs["jaxgfx"], outs["jaxgfx_split"])
                )
            if "llvmpipe" in best:
                row["jaxgfx/llvmpipe"] = best["jaxgfx"] / best["llvmpipe"]
                if split is not None:
                    row["split/llvmpipe"] = best["jaxgfx_split"] / best["llvmpipe"]
            rows.append(row)
            if args.out:
                save_png(Path(args.out) / f"{tag}_{w}x{h}_depth.png", depth_image(depth))
                if "llvmpipe" in outs:
                    save_png(
                        Path(args.out) / f"{tag}_{w}x{h}_llvmpipe_depth.png",
                        depth_image(outs["llvmpipe"][0].astype(np.float32)),
                    )
    return rows


def batch_table(args, peers_for, raster=None) -> list[dict]:
    """``raster``: the one-frame table's ``jax.jit(rasterize)`` (``--quick``'s loop uses it)."""
    from jax.sharding import NamedSharding
    from jax.sharding import PartitionSpec as P

    from jaxgfx.camera import orbit_cameras
    from jaxgfx.raster import rasterize

    _, m = bunny(args.quick)
    v = np.asarray(m.vertices, np.float32)
    f = np.asarray(m.faces, np.int32)
    nrm = np.asarray(m.vertex_normals, np.float32)
    c = 0.5 * (m.bounds[0] + m.bounds[1])
    r = 0.5 * float(np.linalg.norm(m.bounds[1] - m.bounds[0]))
    (w, h), batches = ((128, 96), (2,)) if args.quick else ((512, 384), BATCHES)
    if args.batches:
        batches = tuple(int(b) for b in args.batches.split(","))
    peers = [p for p in peers_for(v, f) if p.name != "trimesh+embree"]  # one thread: too slow
    kinds = {
        "depth": lambda cam: rasterize(cam, v, f).depth,
        "colour+depth": lambda cam: rasterize(cam, v, f, nrm)[:2],
    }
    if args.quick:  # the smoke test: one output kind compiles half as many programs
        kinds.pop("colour+depth")
    ndev = len(jax.devices())
    mesh = jax.make_mesh((ndev,), ("batch",))
    rows = []
    for b in batches:
        cams = orbit_cameras(c, 2.4 * r, b, 20.0, 50.0, w, h, 0.01 * r, 100 * r)
        each = [jax.tree_util.tree_map(lambda x, i=i: x[i], cams) for i in range(b)]
        # The documented way to use every core: the batch sharded over one device per core.
        spread = jax.device_put(cams, NamedSharding(mesh, P("batch"))) if b % ndev == 0 else None
        peer_methods: dict = {}
        for p in peers:
            state = p.prepare(each)
            peer_methods[p.name] = lambda p=p, state=state: p.run(state)
            p.run(state)
        for kind, one in kinds.items():
            single, batched = jax.jit(one), jax.jit(jax.vmap(one))
            if args.quick and raster is not None and kind == "depth":
                # quick: the loop draws with the one-frame table's program (colour and depth,
                # same mesh and size), one program less to compile
                single = lambda cam: raster(cam, v, f, v).depth  # noqa: E731
            methods = {
                "loop": lambda each=each, single=single: jax.block_until_ready(
                    [single(cam) for cam in each]
                ),
                "vmap": lambda cams=cams, batched=batched: jax.block_until_ready(batched(cams)),
            }
            if spread is not None and ndev > 1:
                methods["vmap_sharded"] = lambda spread=spread, batched=batched: (
                    jax.block_until_ready(batched(spread))
                )
            t0 = time.perf_counter()
            for fn in methods.values():
                fn()  # compile
            compile_s = time.perf_counter() - t0
            cpu: dict = {}
            best, outs = best_rounds({**methods, **peer_methods}, args.rounds, cpu)
            depth = np.asarray(outs["vmap"] if kind == "depth" else outs["vmap"][1])
            loop = [o if kind == "depth" else o[1] for o in outs["loop"]]
            loop_depth = np.stack([np.asarray(o) for o in loop])
            row = dict(cameras=b, output=kind, size=f"{w}x{h}", devices=ndev, compile_s=compile_s)
            for k, t in best.items():
                row[f"{k}_fps"] = b / t
            for k in ("vmap", "loop"):
                row[f"{k}_cpu_ms"] = cpu[k] / b * 1e3  # process CPU time per frame
            row["vmap/loop"] = best["loop"] / best["vmap"]
            if "vmap_sharded" in best:
                row["sharded/loop"] = best["loop"] / best["vmap_sharded"]
                sd = outs["vmap_sharded"] if kind == "depth" else outs["vmap_sharded"][1]
                row["sharded_devices"] = len(sd.sharding.device_set)
            row["vmap_vs_loop_coverage"] = bool(
                np.array_equal(np.isfinite(depth), np.isfinite(loop_depth))
            )
            for p in peers:
                row[f"agree_{p.name}"] = f"{agreement(depth, outs[p.name]) * 100:.3f}%"
            rows.append(row)
    return rows


STRIPE_RULES = {"one pass": None, "stripes <= 2^18 px": 1 << 18, "stripes <= 2^16 px": 1 << 16}
"""The ``--stripes`` table's shading rules: the whole frame at once, or rows in stripes of at
most that many pixels (``lax.map``); 2^18 is XLA:CPU's rule in ``jaxgfx._src.raster``."""


def stripes_table(args) -> list[dict]:
    """One bunny frame (colour and depth) with its shading in stripes of rows or in one pass.

    Each rule is its own ``jax.jit(rasterize)``, traced with ``jaxgfx._src.raster._stripes``
    replaced by the rule's stripe count; the rules are timed in interleaved rounds.  The
    frames must agree: the same face ids, colours within float rounding.
    """
    from unittest import mock

    import jaxgfx._src.raster as raster_mod
    from jaxgfx.camera import look_at

    name, tag, mesh, view = next(iter(scenes(args.quick)))
    v = np.asarray(mesh.vertices, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    rule_of = raster_mod._stripes
    rows = []
    for w, h in [(128, 96)] if args.quick else [(512, 384), (1024, 768)]:
        cam = look_at(view["eye"], view["target"], 50.0, w, h, view["near"], view["far"])
        methods, counts = {}, {}
        for rule, pixels in STRIPE_RULES.items():
            n = 1 if pixels is None else rule_of(h, w, pixels)
            # A function of its own per rule: jit's trace cache is keyed by the function.
            fn = jax.jit(lambda cam, v, f, a: raster_mod.rasterize(cam, v, f, a))
            with mock.patch.object(raster_mod, "_stripes", lambda h, w, n=n: n):
                jax.block_until_ready(fn(cam, v, f, v))  # traced and compiled here
            methods[rule] = lambda fn=fn, cam=cam: jax.block_until_ready(fn(cam, v, f, v))
            counts[rule] = n
        cpu: dict = {}
        best, outs = best_rounds(methods, args.rounds, cpu)
        ref = outs["one pass"]
        for rule in methods:
            out = outs[rule]
            rows.append(
                dict(
                    mesh=name,
                    size=f"{w}x{h}",
                    rule=rule,
                    stripes=counts[rule],
                    ms=best[rule] * 1e3,
                    vs_one_pass=best[rule] / best["one pass"],
                    cpu_ms=cpu[rule] * 1e3,
                    cpu_vs_one_pass=cpu[rule] / cpu["one pass"],
                    same_faces=bool(np.array_equal(out.tri_id, ref.tri_id)),
                    color_max_diff=float(np.max(np.abs(np.asarray(out.color - ref.color)))),
                )
            )
    return rows


def figure(path: Path, frame_rows: list[dict], batch_rows: list[dict]) -> None:
    """Left: ms per frame for each scene and size; right: frames/s against the batch size."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxgfx.io import atomic_write

    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    methods = ["jaxgfx", "jaxgfx_split", "open3d", "llvmpipe", "trimesh+embree"]
    methods = [k for k in methods if any(f"{k}_ms" in r for r in frame_rows)]
    names = {"jaxgfx_split": "jaxgfx, rasterize(devices=all)"}
    labels = [f"{r['mesh'].split(' ')[0]}\n{r['size']}" for r in frame_rows]
    x = np.arange(len(frame_rows))
    bar = 0.8 / len(methods)
    for i, k in enumerate(methods):
        ys = [r.get(f"{k}_ms", np.nan) for r in frame_rows]
        ax[0].bar(x + (i - (len(methods) - 1) / 2) * bar, ys, bar, label=names.get(k, k))
    ax[0].set_xticks(x, labels)
    ax[0].set_yscale("log")
    ax[0].set_ylabel("ms per frame (lower is better)")
    ax[0].set_title("one frame")
    ax[0].legend()
    depth_rows = [r for r in batch_rows if r["output"] == "depth"]
    bs = [r["cameras"] for r in depth_rows]
    names = {
        "vmap": "jit(vmap(rasterize)), one device",
        "vmap_sharded": "jit(vmap(rasterize)), batch sharded over every core",
        "loop": "loop of jit(rasterize)",
    }
    for k in ["vmap", "vmap_sharded", "loop", "open3d", "llvmpipe"]:
        ys = [r.get(f"{k}_fps", np.nan) for r in depth_rows]
        if not np.all(np.isnan(ys)):
            ax[1].plot(bs, ys, "o-", label=names.get(k, k))
    ax[1].set_xscale("log", base=2)
    ax[1].set_yscale("log")
    ax[1].set_xlabel("cameras per batch")
    ax[1].set_ylabel("frames / s (higher is better)")
    ax[1].set_title(f"bunny {batch_rows[0]['size']}, batches, depth only")
    ax[1].legend()
    fig.suptitle(machine(), fontsize=8)
    fig.tight_layout()
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--quick", action="store_true", help="3.8k-triangle bunny only, 128x96, a batch of 2"
    )
    ap.add_argument("--out", default=None, help="directory for table (md/json) and figures (png)")
    ap.add_argument(
        "--rounds", type=int, default=None, help="interleaved timing rounds (default 5; quick 2)"
    )
    ap.add_argument(
        "--batches", default=None, help="comma-separated camera counts (default 1,8,32,128)"
    )
    ap.add_argument("--no-frames", action="store_true", help="only the batch table")
    ap.add_argument(
        "--stripes",
        action="store_true",
        help="only the shading-stripes table: one bunny frame, its shading in one pass or in "
        "stripes of rows",
    )
    ap.add_argument(
        "--fresh-memory",
        action="store_true",
        help="skip jaxgfx.keep_freed_memory(): large buffers come fresh from the OS every "
        "call, as in a script that does not call it",
    )
    args = ap.parse_args(argv)
    # As the jaxgfx command does: XLA:CPU's calls reuse freed memory (no fresh pages).
    import jaxgfx

    kept = False if args.fresh_memory else jaxgfx.keep_freed_memory()
    args.rounds = args.rounds or (2 if args.quick else 5)
    # One host device per core for the sharded renderer, before JAX's backends start.
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        jax.config.update("jax_num_cpu_devices", _cores())
    if args.stripes:
        return _stripes_main(args, kept)
    from experiments._raster_peers import load_peers
    from jaxgfx.raster import rasterize

    skipped: dict = {}

    def peers_for(v, f):
        peers, why = load_peers(v, f)
        skipped.update(why)
        return peers

    raster = jax.jit(rasterize)  # one jit for both tables: equal shapes compile once
    ndev = len(jax.devices())
    # Not in --quick (CI runs it): one more compile for a column a quick run cannot judge.
    split = None
    if ndev > 1 and not args.quick:
        split = jax.jit(functools.partial(rasterize, devices=ndev))
    frame_rows = [] if args.no_frames else one_frame_table(args, peers_for, raster, split)
    batch_rows = batch_table(args, peers_for, raster)
    meta = dict(
        machine=machine(),
        command="python -m experiments.bench_raster" + (" --quick" if args.quick else ""),
        rounds=args.rounds,
        depth_rtol=RTOL,
        skipped_peers=skipped,
        note="best of interleaved rounds, compile excluded; agreement: both empty or both "
        f"hit within {RTOL:g} relative camera z",
    )
    cols = ["mesh", "triangles", "size", "compile_s", "jaxgfx_ms"]
    first = frame_rows[0] if frame_rows else {}
    cols += [c for c in first if c.endswith("_ms") and c != "jaxgfx_ms"]
    cols += [c for c in ("jaxgfx/llvmpipe", "split/llvmpipe", "split_equal") if c in first]
    cols += [c for c in first if c.startswith("agree_")] + ["coverage"]
    keys = list(dict.fromkeys(k for r in batch_rows for k in r))  # every row's, in order
    bcols = ["cameras", "output", "size", "devices"]
    bcols += [c for c in keys if c.endswith("_fps")]
    bcols += [c for c in ("vmap/loop", "sharded/loop", "sharded_devices") if c in keys]
    bcols += ["vmap_cpu_ms", "loop_cpu_ms", "vmap_vs_loop_coverage"]
    bcols += [c for c in keys if c.startswith("agree_")]
    skip_text = "".join(f"\n\nskipped peer {k}: {why}" for k, why in skipped.items())
    md = (
        ("## One frame (ms)\n\n" + markdown_table(frame_rows, cols) + "\n\n" if frame_rows else "")
        + "## Batches (frames/s; agreement of the vmap frames)\n\n"
        + markdown_table(batch_rows, bcols)
        + f"\n\nmachine: {meta['machine']}; {args.rounds} rounds\n\n{meta['note']}{skip_text}\n"
    )
    print(md)
    if args.out:
        write_table(
            args.out,
            "Rasterizer vs CPU peers (open3d Embree, Mesa llvmpipe, trimesh+embree)",
            md,
            dict(meta, rows=frame_rows, batch_rows=batch_rows),
        )
        if frame_rows:
            figure(Path(args.out) / "bench_raster.png", frame_rows, batch_rows)
    return 0


def _stripes_main(args, kept: bool) -> int:
    """``--stripes``: prints (and with ``--out`` writes) the shading-stripes table."""
    rows = stripes_table(args)
    command = "python -m experiments.bench_raster --stripes" + (
        " --fresh-memory" if args.fresh_memory else ""
    )
    cols = ["mesh", "size", "rule", "stripes", "ms", "vs_one_pass", "cpu_ms", "cpu_vs_one_pass"]
    cols += ["same_faces", "color_max_diff"]
    md = (
        "## Shading in stripes of rows against one pass (ms per frame, colour and depth; "
        "cpu_ms: process CPU time, every thread)\n\n"
        + markdown_table(rows, cols)
        + f"\n\nmachine: {machine()}; {args.rounds} rounds, best round; freed memory kept "
        f"for reuse (keep_freed_memory): {kept}\n"
    )
    print(md)
    if args.out:
        meta = dict(machine=machine(), command=command, rounds=args.rounds, kept_memory=kept)
        write_table(
            args.out, "Rasterizer shading: stripes of rows or one pass", md, dict(meta, rows=rows)
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
