"""Sweep scaling over host cores: one sharded batch of orbit frames on 1, 2, ... CPU devices.

Issue 14 item 3 target: a batch sweep on 2 cores >= 1.7x one core.  XLA:CPU runs one
computation on one core (plus whatever intra-op threads it finds); one host device per core
(``jax_num_cpu_devices``, the in-process twin of
``XLA_FLAGS=--xla_force_host_platform_device_count``, set here before JAX starts) lets
:func:`jaxgfx.sweep.sharded_renderer` run the shards side by side.  Each device count renders
the same batch (the bunny, or a torus without the data folder) in interleaved rounds; the
table gives the median seconds, frames/s, the speed-up over one device and the process's CPU
time per wall second (about the devices' count when they really run side by side on an idle
machine; on a loaded one every number is bounded by the CPU share the scheduler gives).  A
control row runs a plain ``fori_loop`` the same way.

Usage::

    python -m experiments.sweep_scaling --quick --out out/sweep_scaling
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from experiments.common import DATA
from jaxgfx._src.report import machine, markdown_table, write_table


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="16 frames of 80x60, 3 rounds")
    ap.add_argument("--out", default=None, help="directory for table.md / table.json")
    args = ap.parse_args(argv)
    cores = _cores()
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        jax.config.update("jax_num_cpu_devices", cores)  # before JAX's backends start
    from jaxgfx.camera import orbit_cameras
    from jaxgfx.compose import background, composite, to_uint8
    from jaxgfx.io import load_mesh, mesh_arrays
    from jaxgfx.scene import mesh_pass, render_mesh_pass
    from jaxgfx.sweep import sharded_renderer

    n, (w, h), rounds = (16, (80, 60), 3) if args.quick else (32, (160, 120), 7)
    bunny = DATA / "meshes" / "bun_zipper_res2.ply"
    if bunny.is_file():
        mp, scene = mesh_pass(*mesh_arrays(load_mesh(bunny))), "bunny res2"
    else:
        import trimesh

        m = trimesh.creation.torus(1.0, 0.4, major_sections=64, minor_sections=32)
        mp = mesh_pass(m.vertices.astype(np.float32), m.faces.astype(np.int32))
        scene = "torus"
    v = np.asarray(mp.vertices)
    c, r = 0.5 * (v.min(0) + v.max(0)), float(np.linalg.norm(v.max(0) - v.min(0)))
    cams = orbit_cameras(c, 1.5 * r, n, 20.0, 45.0, w, h, 0.01 * r, 10 * r)

    def frame(cam):
        fr = composite([background(cam), render_mesh_pass(cam, mp)])
        return {"color": to_uint8(fr.color), "depth": fr.depth}

    def spin(x):  # control: sequential scalar work, no intra-op parallelism to find
        return jax.lax.fori_loop(0, 2000, lambda i, x: jnp.sin(x) * 1.0001 + 0.01, x)

    counts = sorted({1, 2, len(jax.devices())} & set(range(1, len(jax.devices()) + 1)))
    rows = []
    for name, fn, batch in (
        (f"sweep {scene} {n}x{w}x{h}", frame, cams),
        ("control fori_loop", spin, np.ones((max(counts) * 2, 20000), np.float32)),
    ):
        runs = {d: sharded_renderer(fn, jax.devices()[:d]) for d in counts}
        ref = {d: run(batch) for d, run in runs.items()}  # compile
        same = (
            all(np.array_equal(ref[counts[0]]["color"], o["color"]) for o in ref.values())
            if (isinstance(ref[counts[0]], dict))
            else None
        )
        wall: dict = {d: [] for d in counts}
        cpu: dict = {d: [] for d in counts}
        for _ in range(rounds):
            for d, run in runs.items():
                c0, t0 = time.process_time(), time.perf_counter()
                run(batch)
                wall[d].append(time.perf_counter() - t0)
                cpu[d].append((time.process_time() - c0) / wall[d][-1])
        base = statistics.median(wall[counts[0]])
        for d in counts:
            med = statistics.median(wall[d])
            rows.append(dict(work=name, devices=d, median_s=med, items_per_s=len(
                jax.tree_util.tree_leaves(batch)[0]) / med, speedup=base / med,
                cpu_per_wall=statistics.median(cpu[d]), identical_frames=same))  # fmt: skip
    cols = ["work", "devices", "median_s", "items_per_s", "speedup", "cpu_per_wall"]
    text = f"Machine: {machine()}; {rounds} interleaved rounds\n\n" + markdown_table(rows, cols)
    print(text)
    if args.out:
        write_table(args.out, "Sweep scaling over host cores", text, dict(rows=rows))
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
