"""Helpers shared by every experiment: machine line, timing, tables, data folder, limb rigs.

Timing, the machine line and the Markdown/JSON tables are the library's own (the CLI's
``jaxgfx demo`` writes its timing table with the same functions).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import jax
import numpy as np

from jaxgfx import skin
from jaxgfx._src.report import machine, markdown_table, time_jitted, write_table

__all__ = [
    "DATA",
    "best_of",
    "best_rounds",
    "machine",
    "time_jitted",
    "markdown_table",
    "write_table",
    "cylinder",
    "limb_rig",
    "limb_binding",
    "random_poses",
]


def best_of(fn, reps: int = 3) -> float:
    """Fastest wall time of ``reps`` calls of ``fn`` (its result blocked on), in seconds."""
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return min(times)


# Real data no one here made (``../shared/data`` beside the checkout; JAXGFX_DATA overrides).
DATA = Path(
    os.environ.get("JAXGFX_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
)


def best_rounds(methods: dict, rounds: int, cpu: dict | None = None) -> tuple[dict, dict]:
    """Runs every method once per round, interleaved; returns (best seconds, last outputs).

    Load from other processes hits every method alike.  Each output is blocked on.

    With ``cpu`` (a dict) it also gets each method's least process CPU time of a round
    (``time.process_time``: every thread, so 2 busy cores count twice), which load from
    other processes disturbs less than wall time.
    """
    best = {k: float("inf") for k in methods}
    if cpu is not None:
        cpu.update({k: float("inf") for k in methods})
    outs: dict = {}
    for _ in range(rounds):
        for k, fn in methods.items():
            outs.pop(k, None)  # free the last round's outputs before timing the next
            t0, c0 = time.perf_counter(), time.process_time()
            outs[k] = jax.block_until_ready(fn())
            best[k] = min(best[k], time.perf_counter() - t0)
            if cpu is not None:
                cpu[k] = min(cpu[k], time.process_time() - c0)
    return best, outs


def cylinder(n_around: int, n_along: int, radius: float, length: float, *, caps: bool = True):
    """Closed cylinder along +z: vertices (V, 3), normals (V, 3), faces (F, 3) (outward)."""
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    z = np.linspace(0.0, length, n_along)
    zz, aa = np.meshgrid(z, a, indexing="ij")
    v = np.stack([radius * np.cos(aa), radius * np.sin(aa), zz], -1).reshape(-1, 3)
    n = np.stack([np.cos(aa), np.sin(aa), 0 * zz], -1).reshape(-1, 3)
    faces = []
    for i in range(n_along - 1):
        for j in range(n_around):
            a0 = i * n_around + j
            a1 = i * n_around + (j + 1) % n_around
            b0, b1 = a0 + n_around, a1 + n_around
            faces += [[a0, a1, b1], [a0, b1, b0]]
    faces = np.asarray(faces, np.int64)
    if caps:
        base = len(v)
        v = np.concatenate([v, [[0, 0, 0], [0, 0, length]]])
        n = np.concatenate([n, [[0, 0, -1], [0, 0, 1]]])
        ring0 = np.arange(n_around)
        ring1 = (n_along - 1) * n_around + ring0
        cap0 = np.stack([np.full(n_around, base), np.roll(ring0, -1), ring0], 1)
        cap1 = np.stack([np.full(n_around, base + 1), ring1, np.roll(ring1, -1)], 1)
        faces = np.concatenate([faces, cap0, cap1])
    return v.astype(np.float32), n.astype(np.float32), faces.astype(np.int32)


def limb_rig(num_splines: int = 3, segment: float = 1.0, stiffness: float = 4.0):
    """A chain of straight splines along +z, each hanging from its parent's end (Fig. 5.16)."""
    pts = []
    for k in range(num_splines):
        z0 = 2 * segment * k
        pts.append([[0, 0, z0], [0, 0, z0 + segment], [0, 0, z0 + 2 * segment]])
    return skin.make_rig(
        np.asarray(pts, np.float32),
        stiffness=stiffness,
        reference_normal=np.tile([[1.0, 0.0, 0.0]], (num_splines, 1)),
        parent=[-1] + list(range(num_splines - 1)),
        parent_point=[0] + [2] * (num_splines - 1),
    )


def limb_binding(rig, vertices, normals, *, blend: float = 0.3, influences: int = 3):
    """Bind a limb along +z: weights blend between consecutive splines over ``blend`` length.

    Every vertex gets ``influences`` (index, weight) pairs, padded with zero weights on valid
    spline indices, as the thesis's GPU layout does (three splines per vertex).
    """
    k = rig.num_splines
    seg = float(rig.bind.points[0, 2, 2] - rig.bind.points[0, 0, 2])
    z = vertices[:, 2] / seg  # position in spline units
    own = np.clip(np.floor(z), 0, k - 1).astype(int)
    frac = z - own
    nxt = np.clip(own + 1, 0, k - 1)
    prv = np.clip(own - 1, 0, k - 1)
    # blend towards the next spline near the end of the current one, and the previous near start
    t_next = np.clip((frac - (1 - blend / 2 / seg)) / (blend / seg), 0, 1) * (own < k - 1)
    t_prev = np.clip(((blend / 2 / seg) - frac) / (blend / seg), 0, 1) * (own > 0)
    idx = np.stack([own, nxt, prv], 1)[:, :influences]
    w = np.stack([1 - t_next - t_prev, t_next, t_prev], 1)[:, :influences]
    w = w / w.sum(1, keepdims=True)
    return skin.bind_mesh(rig, vertices, idx.astype(np.int32), w, normals=normals)


def random_poses(rig, count: int, key, *, max_bend: float = 1.2, max_twist: float = 1.5):
    """``count`` stacked random poses (bends about random axes at p1 and p2, random twists)."""
    k = rig.num_splines
    k1, k2, k3 = jax.random.split(key, 3)
    aa1 = jax.random.normal(k1, (count, k, 3)) * max_bend / 3
    aa2 = jax.random.normal(k2, (count, k, 3)) * max_bend / 2
    twist = jax.random.uniform(k3, (count, k), minval=-max_twist, maxval=max_twist)
    rot = jax.vmap(jax.vmap(skin.axis_angle_to_matrix))

    def one(a1, a2, tw):
        return skin.forward_kinematics(rig, rot(a1[None])[0], rot(a2[None])[0], twist=tw)

    return jax.vmap(one)(aa1, aa2, twist)
