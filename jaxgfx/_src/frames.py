"""Stacks of frames: run a per-frame kernel over a batch, split over this process's devices.

Used by the rasterizer (:mod:`jaxgfx._src.zbuffer`, :mod:`jaxgfx.raster`) and, for the mesh
alone, by :mod:`jaxgfx.sweep`, so that they build their device meshes the same way.

A *stack* is a tuple of pytrees whose leaves all have a leading axis of 1 (shared by every
frame) or B (one per frame).  :func:`stacked_vmap` turns a per-frame function into a
``custom_vmap`` kernel over stacks: ``jax.vmap`` folds its axis into the stack, and the kernel
runs the frames one after the other (``lax.map``), each frame's temporaries sized for one
frame, instead of a vmapped program whose every buffer is multiplied by the batch.  With
several local devices (host devices on CPU) the frames are split over them (``shard_map``).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

__all__ = ["BATCH_AXIS", "batch_mesh", "split_mesh", "stack_size", "map_frames", "stacked_vmap"]

BATCH_AXIS = "batch"


def batch_mesh(devices=None, axis: str = BATCH_AXIS) -> Mesh:
    """1-D mesh (axis ``axis``) over ``devices`` (default: all devices of all processes)."""
    devs = np.asarray(jax.devices() if devices is None else list(devices))
    if devs.size == 0:
        raise ValueError("devices: no devices to build a mesh over")
    return Mesh(devs, (axis,))


def split_mesh(items: int) -> Mesh | None:
    """Mesh of this process's devices to split ``items`` batch items over, or ``None``.

    ``None`` (run on one device, as without a mesh) when there is only one local device or
    one item, or when the caller is already inside a mesh context (a ``shard_map`` such as
    :func:`jaxgfx.sweep.sharded_renderer`'s, or a mesh the user set): there the batch has
    already been split, or the user placed it.  Only local devices: another process's
    devices would turn one process's render into a collective program.  (Inside a user's
    ``jit``, inputs committed to one device then meet this mesh's devices and JAX refuses
    the program; such a caller sets its own mesh with ``jax.set_mesh``.)
    """
    devs = jax.local_devices()
    if len(devs) < 2 or items < 2 or not jax.sharding.get_abstract_mesh().empty:
        return None
    # As few devices as give the same items per device: 6 items on 4 devices take 2 rounds
    # either way, and 3 devices need no padded items (4 would render 2 copies).
    per_device = -(-items // len(devs))
    return batch_mesh(devs[: -(-items // per_device)])


def _lead(x) -> int:
    return int(x.shape[0])


def stack_size(args) -> int:
    """The stack's frame count B; every leaf's leading axis must be 1 or B."""
    sizes = {_lead(x) for x in jax.tree_util.tree_leaves(args)}
    frames = max(sizes)
    if not sizes <= {1, frames}:
        raise ValueError(f"leading axes must be 1 or one common size, got {sorted(sizes)}")
    return frames


def _map_local(frame_fn: Callable, args: tuple):
    """``frame_fn`` over the stack's frames one after the other, on one device."""
    frames = stack_size(args)

    def one(k):
        return frame_fn(*jax.tree_util.tree_map(lambda x: x[0 if _lead(x) == 1 else k], args))

    if frames == 1:
        return jax.tree_util.tree_map(lambda x: x[None], one(0))
    return jax.lax.map(one, jnp.arange(frames, dtype=jnp.int32))


def map_frames(frame_fn: Callable, args: tuple):
    """Stacked outputs (B, ...) of ``frame_fn(*one_frame_args)`` for every frame of ``args``.

    With several local devices (:func:`split_mesh`) the frames are split over them with
    ``shard_map``: XLA:CPU runs one computation on one core, so this is what puts a batch
    on every core.  The batch is padded to a multiple of the devices with copies of its last
    frame (dropped after); shared leaves (leading 1) are replicated.  Every device runs the
    same frame-by-frame program, so integer results equal the one-device path's exactly.
    """
    frames = stack_size(args)
    mesh = split_mesh(frames)
    if mesh is None:
        return _map_local(frame_fn, args)
    pad = -frames % mesh.devices.size

    def padded(x):
        if _lead(x) == 1 or not pad:
            return x
        return jnp.concatenate([x, jnp.broadcast_to(x[-1:], (pad, *x.shape[1:]))])

    specs = jax.tree_util.tree_map(lambda x: P() if _lead(x) == 1 else P(BATCH_AXIS), args)
    # check_vma=False: the kernel's constants (empty z-buffers, ...) are not typed as
    # device-varying; no collectives are needed (each device's frames are independent).
    run = jax.shard_map(
        lambda *a: _map_local(frame_fn, a),
        mesh=mesh,
        in_specs=specs,
        out_specs=P(BATCH_AXIS),
        check_vma=False,
    )
    out = run(*jax.tree_util.tree_map(padded, args))
    return jax.tree_util.tree_map(lambda x: x[:frames], out) if pad else out


def stacked_vmap(frame_fn: Callable):
    """``custom_vmap`` kernel ``kernel(*args) -> stacked outputs`` over stacks of frames.

    ``kernel`` is :func:`map_frames` of ``frame_fn``.  Its vmap rule folds the vmapped axis
    into the stack, (A, B) -> (A*B), so nested vmaps still give one stack; an argument the
    vmap does not touch and that is shared (every leaf leading 1) stays shared.  Build it
    once per static configuration (cache the caller), so that jit caches hit.
    """

    @jax.custom_batching.custom_vmap
    def kernel(*args):
        return map_frames(frame_fn, args)

    @kernel.def_vmap
    def fold(axis_size, in_batched, *args):
        def inner(x, batched):
            return x.shape[1] if batched else x.shape[0]

        frames = max(
            inner(x, bt)
            for a, b in zip(args, in_batched, strict=True)
            for x, bt in zip(
                jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True
            )
        )

        def widen(x, batched):
            if not batched:
                x = jnp.broadcast_to(x[None], (axis_size, *x.shape))
            x = jnp.broadcast_to(x, (axis_size, frames, *x.shape[2:]))
            return x.reshape(axis_size * frames, *x.shape[2:])

        folded = []
        for a, b in zip(args, in_batched, strict=True):
            flags = jax.tree_util.tree_leaves(b)
            shared = not any(flags) and all(_lead(x) == 1 for x in jax.tree_util.tree_leaves(a))
            folded.append(a if shared else jax.tree_util.tree_map(widen, a, b))
        out = kernel(*folded)
        out = jax.tree_util.tree_map(lambda x: x.reshape(axis_size, frames, *x.shape[1:]), out)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return kernel
