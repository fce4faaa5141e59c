"""Sweep scaling over host cores: one sharded batch of orbit frames on 1 core, then 2, ... cores.

The target: a batch sweep on 2 cores >= 1.7x one core.  "One core" is taken
literally: every thread of this process is pinned to one CPU (``sched_setaffinity``) for the
baseline, because one JAX device is NOT one core on XLA:CPU: its thunk runtime splits large
loop fusions over an intra-op thread pool with one thread per core, so a single device
already keeps two cores busy part of the time (the ``two_plus`` column shows how much).
Each configuration renders the same batch (the bunny, or a torus without the data folder) in
interleaved rounds, switching the process's affinity between rounds; host devices come from
``jax_num_cpu_devices`` (the in-process twin of
``XLA_FLAGS=--xla_force_host_platform_device_count``, set here before JAX starts) and
:func:`jaxgfx.sweep.sharded_renderer` runs the shards side by side.

The table gives the median seconds, frames/s, the speed-up over one core, the process's CPU
time per wall second and the parallelism the program offers, sampled every millisecond from
``/proc``: the mean number of runnable threads (``runnable``) and the share of the time with
two or more (``two_plus``).  A runnable thread is running or waiting for a core, so this
design check does not depend on the load, unlike the times: on a loaded machine every time
is bounded by the CPU share the scheduler gives.  A control row runs a small ``fori_loop``
(too small for intra-op threads) the same way.

Usage::

    python -m experiments.sweep_scaling --quick --out out/sweep_scaling
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import threading
import time

import jax
import jax.numpy as jnp
import numpy as np

from experiments.common import DATA
from jaxgfx._src.report import machine, markdown_table, write_table


def _allowed() -> set[int]:
    """The CPUs this process may run on."""
    try:
        return set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return set(range(os.cpu_count() or 1))


def _cores() -> int:
    return len(_allowed())


def _pin(cpus: set[int]) -> None:
    """Pins every thread of this process (XLA's pools included) to ``cpus``."""
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(tid), cpus)
        except OSError:  # a thread that just ended
            pass


class _Runnable:
    """Samples, every millisecond while in use, how many threads of this process are runnable.

    A thread in state R is running or waiting for a core, so the count is the parallelism the
    program offers whatever the load (spin-waiting pool threads count too).
    """

    def __enter__(self):
        self.counts: list[int] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def _loop(self) -> None:
        me = str(threading.get_native_id())
        while not self._stop.is_set():
            k = 0
            for tid in os.listdir("/proc/self/task"):
                if tid == me:
                    continue
                try:
                    with open(f"/proc/self/task/{tid}/stat") as fh:
                        k += fh.read().rsplit(")", 1)[1].split()[0] == "R"
                except (OSError, IndexError):
                    pass
            self.counts.append(k)
            time.sleep(0.001)

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="4 frames of 80x60, 1 round")
    ap.add_argument("--out", default=None, help="directory for table.md / table.json")
    args = ap.parse_args(argv)
    # As the jaxgfx command does: XLA:CPU's calls reuse freed memory (no fresh pages).
    import jaxgfx

    jaxgfx.keep_freed_memory()
    cores = _cores()
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        jax.config.update("jax_num_cpu_devices", cores)  # before JAX's backends start
    from jaxgfx.camera import orbit_cameras
    from jaxgfx.compose import background, composite, to_uint8
    from jaxgfx.io import load_mesh, mesh_arrays
    from jaxgfx.scene import mesh_pass, render_mesh_pass
    from jaxgfx.sweep import sharded_renderer

    # Quick: a batch of 4 frames, one round (CI time; the compiled programs are the same).
    n, (w, h), rounds = (4, (80, 60), 1) if args.quick else (32, (160, 120), 7)
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

    spins = 20_000 if args.quick else 200_000

    def spin(x):  # control: sequential work on 64 floats, too small for intra-op threads
        return jax.lax.fori_loop(0, spins, lambda i, x: jnp.sin(x) * 1.0001 + 0.01, x)

    cpus = sorted(_allowed())
    n_dev = len(jax.devices())
    configs = [(1, 1)] + [(c, d) for c, d in ((2, 1), (2, 2), (n_dev, n_dev)) if c <= len(cpus)]
    configs = list(dict.fromkeys(configs))  # (cores, devices), without repeats
    rows = []
    for name, fn, batch in (
        (f"sweep {scene} {n}x{w}x{h}", frame, cams),
        ("control fori_loop", spin, np.ones((2 * n_dev, 64), np.float32)),
    ):
        runs = {d: sharded_renderer(fn, jax.devices()[:d]) for _, d in configs}
        ref = {d: run(batch) for d, run in runs.items()}  # compile
        same = (
            all(np.array_equal(ref[1]["color"], o["color"]) for o in ref.values())
            if isinstance(ref[1], dict)
            else None
        )
        wall: dict = {k: [] for k in configs}
        cpu: dict = {k: [] for k in configs}
        runnable: dict = {k: [] for k in configs}
        for _ in range(rounds):
            for cores, d in configs:
                _pin(set(cpus[:cores]))
                with _Runnable() as sampled:
                    c0, t0 = time.process_time(), time.perf_counter()
                    runs[d](batch)
                    wall[(cores, d)].append(time.perf_counter() - t0)
                    cpu[(cores, d)].append((time.process_time() - c0) / wall[(cores, d)][-1])
                runnable[(cores, d)] += sampled.counts
        _pin(set(cpus))
        base = statistics.median(wall[(1, 1)])
        for cores, d in configs:
            med = statistics.median(wall[(cores, d)])
            rows.append(dict(work=name, cores=cores, devices=d, median_s=med, items_per_s=len(
                jax.tree_util.tree_leaves(batch)[0]) / med, speedup=base / med,
                cpu_per_wall=statistics.median(cpu[(cores, d)]),
                runnable=float(np.mean(runnable[(cores, d)])),
                two_plus=float(np.mean(np.asarray(runnable[(cores, d)]) >= 2)),
                identical_frames=same))  # fmt: skip
    cols = ["work", "cores", "devices", "median_s", "items_per_s", "speedup", "cpu_per_wall"]
    cols += ["runnable", "two_plus"]
    text = f"Machine: {machine()}; {rounds} interleaved rounds\n\n" + markdown_table(rows, cols)
    print(text)
    if args.out:
        write_table(args.out, "Sweep scaling over host cores", text, dict(rows=rows))
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
