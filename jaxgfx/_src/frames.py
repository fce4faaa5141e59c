"""Batching rules for per-frame kernels and the one ``shard_map`` wrapper of the package.

A renderer's frame is a program of data-dependent loops (the z-buffer's work list, the ray
caster's plane walk).  Batched by plain ``jax.vmap`` every frame of a batch runs as long as the
longest and takes every branch; run one after the other, each frame runs its own program.
Which is faster depends on the backend: on XLA:CPU one frame at a time keeps each frame's
buffers in cache and its loops short, while a GPU or TPU pays a launch and a host sync per
loop iteration, so there the whole batch must advance in each iteration.
:func:`per_frame` gives a per-frame function a ``custom_vmap`` rule that makes that choice
per platform at lowering time (``jax.lax.platform_dependent``), and follows the data: a batch
whose leading axis the user sharded over a mesh (``jax.make_mesh`` and
``jax.device_put(x, NamedSharding(mesh, P("batch")))``) runs each device's frames on that
device; anything else runs where its inputs are.  No device is ever chosen here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np
from jax.sharding import AxisType, Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

__all__ = [
    "BATCHING",
    "BATCH_AXIS",
    "batch_mesh",
    "shard_batch",
    "shard",
    "split_rows",
    "per_frame",
    "check_batching",
]

BATCH_AXIS = "batch"
BATCHING = ("auto", "frames", "vectorized")
"""Batching rules: by platform, frame by frame (``lax.map``), or one vectorized program."""


def check_batching(batching: str) -> str:
    """``batching`` if it names a rule of :data:`BATCHING`; raises ``ValueError`` otherwise."""
    if batching not in BATCHING:
        raise ValueError(f"batching must be one of {BATCHING}, got {batching!r}")
    return batching


def batch_mesh(devices=None, axis: str = BATCH_AXIS, *, explicit: bool = False) -> Mesh:
    """1-D mesh (axis ``axis``) over ``devices`` (default: all devices of all processes).

    ``explicit``: the axis is ``AxisType.Explicit`` (as ``jax.make_mesh`` makes it), so arrays
    placed on it carry their sharding into traced code, where the batching rules read it;
    otherwise it is ``Auto`` (for the sweep helpers, which place their batches themselves).
    """
    devs = np.asarray(jax.devices() if devices is None else list(devices))
    if devs.size == 0:
        raise ValueError("devices: no devices to build a mesh over")
    kind = AxisType.Explicit if explicit else AxisType.Auto
    return Mesh(devs, (axis,), axis_types=(kind,))


def shard_batch(tree, devices=None):
    """``tree`` placed with every leaf's leading (batch) axis split over ``devices``.

    The one step that puts a batch on every core of a CPU (given one host device per core,
    ``jax.config.update("jax_num_cpu_devices", os.cpu_count())`` before JAX starts) or on
    every local accelerator: ``jax.jit(jax.vmap(f))(shard_batch(batch))`` then runs each
    device's items on that device.  Shared inputs stay as they are.

    Args:
        tree: a pytree of arrays with one common leading axis B (e.g. stacked cameras).
        devices: the devices (default: this process's devices); B must be a multiple of
            their number.

    Returns:
        The same tree on a 1-D mesh over ``devices``, sharded along the batch axis (an
        explicit mesh axis: results keep that sharding; ``np.asarray`` or
        ``jax.device_get`` fetches them whole).
    """
    mesh = batch_mesh(jax.local_devices() if devices is None else devices, explicit=True)
    n = mesh.devices.size
    sizes = {int(np.shape(x)[0]) for x in jax.tree_util.tree_leaves(tree) if np.ndim(x) > 0}
    if len(sizes) != 1:
        raise ValueError(f"tree: leaves must share one leading batch axis, got sizes {sizes}")
    size = sizes.pop()
    if size % n:
        raise ValueError(
            f"tree: a batch of {size} does not split evenly over {n} devices; pad it to "
            f"{-(-size // n) * n} items or pass devices="
        )
    return jax.device_put(tree, NamedSharding(mesh, P(BATCH_AXIS)))


def shard(fn: Callable, mesh, in_specs, out_specs) -> Callable:
    """``jax.shard_map(fn)`` over ``mesh``, its arguments first placed as ``in_specs`` say.

    Over explicit mesh axes ``shard_map`` takes arguments only with exactly its specs, so an
    argument placed otherwise (a batch padded on the host, a shared table) is resharded
    first.  ``check_vma=False``: kernels build constants (empty z-buffers, loop counters) that
    are not typed as device-varying, and loops whose carries mix shared and per-device values
    would otherwise fail to trace; each device's work is independent or merged by explicit
    collectives, so nothing relies on the check.
    """
    mapped = jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)
    abstract = getattr(mesh, "abstract_mesh", mesh)

    def placed(*args):
        single = isinstance(in_specs, P) or not isinstance(in_specs, tuple)
        specs = (in_specs,) * len(args) if single else in_specs
        args = tuple(_on_mesh(a, abstract, sp) for a, sp in zip(args, specs, strict=True))
        return mapped(*args)

    return placed


def _on_mesh(tree, mesh, spec):
    """``tree`` resharded to ``spec`` on ``mesh`` where a leaf's sharding differs.

    Only over explicit axes (``jax.make_mesh``'s default): there ``shard_map`` refuses an
    argument whose sharding is not its spec, e.g. one leaf of a batch sharded and one not.
    """
    if AxisType.Explicit not in tuple(getattr(mesh, "axis_types", ())):
        return tree

    def place(x):
        sharding = getattr(jax.typeof(x), "sharding", None)
        have = tuple(getattr(sharding, "spec", ()))
        want = tuple(spec) + (None,) * (np.ndim(x) - len(tuple(spec)))
        if have == want or (not any(have) and not any(want)):
            return x
        with jax.sharding.use_abstract_mesh(mesh):
            return jax.reshard(x, spec)

    return jax.tree_util.tree_map(place, tree)


def _batch_axis(leaves: Sequence[Any]):
    """``(mesh, axis)`` of the first leaf sharded along its leading axis, else ``None``.

    Read from the abstract value, so it sees shardings a user gave with explicit mesh axes
    (``jax.make_mesh``'s default), inside ``jit`` as well as eagerly.
    """
    for x in leaves:
        sharding: Any = getattr(jax.typeof(x), "sharding", None)
        spec = tuple(getattr(sharding, "spec", ()))
        if spec and spec[0] is not None:
            return sharding.mesh, spec[0]
    return None


def split_rows(fn: Callable, rows: Sequence[int]) -> Callable:
    """``fn`` run by each device on its own rows where the row arguments are sharded.

    For kernels whose work is independent per row (per vertex): when the positional
    arguments ``rows`` are sharded along their leading axis (explicit mesh axes), each device
    computes its rows (``shard_map``; the other arguments are shared) and the outputs come
    back sharded the same way; otherwise ``fn`` runs as it is, where its inputs are.
    """
    rows = tuple(rows)

    def wrapped(*args):
        placed = _batch_axis([x for i in rows for x in jax.tree_util.tree_leaves(args[i])])
        if placed is None:
            return fn(*args)
        mesh, axis = placed
        specs = [P(axis) if i in rows else P() for i in range(len(args))]
        return shard(fn, mesh, tuple(specs), P(axis))(*args)

    return wrapped


def per_frame(
    frame_fn: Callable,
    batching: str = "auto",
    chunk: int = 1,
    batch_fn: Callable[[int], Callable] | None = None,
) -> Callable:
    """``frame_fn`` (written for one frame) with a batching rule chosen by platform.

    Under ``jax.vmap`` the batch runs

    * ``"frames"``: one frame after another (``lax.map``), each with its own loop trip counts
      (``chunk`` > 1: chunks of that many frames vectorized, one chunk after another, which
      keeps a chunk's tables in cache for kernels without data-dependent loops);
    * ``"vectorized"``: as one program over the whole batch (``jax.vmap(frame_fn)``): every
      loop iteration advances every frame, so the dependent iterations of a batch are those of
      its slowest frame;
    * ``"auto"``: ``"frames"`` on CPU and ``"vectorized"`` elsewhere, chosen when the program
      is lowered (``jax.lax.platform_dependent``), so one exported program carries both.

    When the batched arguments are sharded along the batch axis, each device runs its own
    frames by the same rule (``shard_map`` over the user's mesh); nested ``vmap`` nests the
    rule.  Arguments the ``vmap`` does not batch are shared by every frame, not copied.

    Args:
        frame_fn: function of one frame's arrays (pytrees allowed), returning a pytree.
        batching: one of :data:`BATCHING` (static).
        chunk: frames per step of the ``"frames"`` rule (static).
        batch_fn: ``batch_fn(n)`` is the function of one frame that the ``"vectorized"``
            rule maps over a batch of ``n`` frames on one device (default ``frame_fn``):
            a kernel whose static sizes follow the batch (the scatter traversal's
            window on an accelerator) takes them from ``n``.

    Returns:
        A function with ``frame_fn``'s signature whose ``vmap`` follows the rule.
    """
    check_batching(batching)
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk must be a positive int, got {chunk!r}")

    @jax.custom_batching.custom_vmap
    def kernel(*args):
        return frame_fn(*args)

    @kernel.def_vmap
    def rule(axis_size, in_batched, *args):
        del axis_size
        flat, tree = jax.tree_util.tree_flatten(args)
        flags = jax.tree_util.tree_leaves(in_batched)
        batched = [x for x, b in zip(flat, flags, strict=True) if b]
        shared = [x for x, b in zip(flat, flags, strict=True) if not b]

        def rebuild(frame, common):
            it_frame, it_common = iter(frame), iter(common)
            leaves = [next(it_frame) if b else next(it_common) for b in flags]
            return jax.tree_util.tree_unflatten(tree, leaves)

        def frames(frame_args, common):
            if chunk > 1:
                return jax.lax.map(
                    lambda one: frame_fn(*rebuild(one, common)), frame_args, batch_size=chunk
                )
            # kernel, not frame_fn: an outer vmap of this map reaches the rule again.
            return jax.lax.map(lambda one: kernel(*rebuild(one, common)), frame_args)

        def vectorized(frame_args, common):
            fn = frame_fn if batch_fn is None else batch_fn(frame_args[0].shape[0])
            return jax.vmap(lambda *one: fn(*rebuild(one, common)))(*frame_args)

        def local(frame_args, common):
            if batching == "frames":
                return frames(frame_args, common)
            if batching == "vectorized":
                return vectorized(frame_args, common)
            return jax.lax.platform_dependent(frame_args, common, cpu=frames, default=vectorized)

        placed = _batch_axis(batched)
        if placed is None:
            out = local(batched, shared)
        else:
            mesh, axis = placed
            run = shard(lambda b, c: local(list(b), list(c)), mesh, (P(axis), P()), P(axis))
            out = run(tuple(batched), tuple(shared))
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return kernel
