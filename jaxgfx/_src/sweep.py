"""Batched, sharded, resumable rendering sweeps.

A sweep renders N items (cameras, or any pytree of per-item parameters with a
leading axis of N) with ``jax.vmap`` in fixed-size chunks.  Each chunk is
sharded over a 1-D device mesh (axis ``"batch"``) with ``NamedSharding``, so
one program uses every local device, and every device of every host once the
user has started JAX's multi-host runtime:

    import jax
    jax.distributed.initialize()  # on every host, before any other JAX call
    # ... then call run_sweep() with identical arguments on every host.

With several processes each host computes its shard; results are gathered
with ``multihost_utils.process_allgather`` and written by process 0 only.  Process 0 alone
reads ``out_dir`` (the manifest check and which chunks are done) and broadcasts its decision,
so every process computes the same chunks even when the others cannot see its disk; the
``on_chunk`` callback runs on process 0 only.  If a process dies, JAX's coordination service
stops the others (after ``heartbeat_timeout_seconds``); starting every process again resumes
from the chunks on process 0's disk.  On CPU the processes talk over TCP with gloo (JAX's
default ``jax_cpu_collectives_implementation``); ``tests/test_sweep.py`` runs two processes on
localhost:

    jax.distributed.initialize("localhost:12345", num_processes=2, process_id=i)

Every finished chunk is written atomically as a compressed ``chunk_XXXXX.npz`` (zlib)
beside a ``manifest.json``; outputs named in ``images`` (8-bit colour frames) are stored
as one PNG per item instead, which is several times smaller than the raw pixels and
directly viewable.  A sweep that is interrupted (Ctrl-C, or even SIGKILL) and started
again with the same arguments skips the chunks already on disk: a chunk counts as done
when its ``.npz`` (written last) and every one of its images are there.  The manifest records
what defines the results (parameters, chunking, a hash of the lowered render function, the
output shapes, an optional version string); a different sweep into the same folder is
refused with a ValueError that names what differs, so results never mix.

One XLA:CPU device uses other cores only inside large fused loops (its intra-op thread
pool); the rest of a program runs on one thread.  To keep every core busy,
give JAX one host device per core before it starts, e.g.
``XLA_FLAGS=--xla_force_host_platform_device_count=8`` or ``jax.config.update(
"jax_num_cpu_devices", 8)`` (``jaxgfx sweep`` does this itself; see ``--devices``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxgfx._src.checks import check_int
from jaxgfx._src.chunks import (
    check_image_outputs,
    chunk_complete,
    chunk_path,
    image_path,
    image_patterns,
    load_sweep,
    read_images,
    write_chunk,
)
from jaxgfx._src.frames import BATCH_AXIS, batch_mesh, shard
from jaxgfx._src.io import save_json

__all__ = [
    "batch_size",
    "device_mesh",
    "ShardedRenderer",
    "sharded_renderer",
    "ShardedMap",
    "sharded_vmap",
    "run_sweep",
    "render_fingerprint",
    "SweepMismatch",
    "load_sweep",
    "chunk_path",
    "image_path",
]


def batch_size(params) -> int:
    """Leading-axis size shared by every leaf of ``params``."""
    sizes = {int(np.shape(x)[0]) for x in jax.tree_util.tree_leaves(params) if np.ndim(x) > 0}
    if len(sizes) != 1:
        raise ValueError(f"params leaves must share one leading batch axis, got sizes {sizes}")
    return sizes.pop()


def device_mesh(devices=None) -> Mesh:
    """1-D mesh over ``devices`` (default: all devices of all processes)."""
    return batch_mesh(devices)


def _slice(params, start: int, stop: int, pad_to: int):
    """Items [start, stop) padded to ``pad_to`` by repeating the last item."""

    def take(x):
        x = np.asarray(x)
        part = x[start:stop]
        if len(part) < pad_to:
            part = np.concatenate([part, np.repeat(part[-1:], pad_to - len(part), axis=0)])
        return part

    return jax.tree_util.tree_map(take, params)


@dataclasses.dataclass(frozen=True)
class ShardedRenderer:
    """``vmap(render_fn)`` jitted once and sharded over a 1-D device mesh.

    Call it with a pytree whose leading axis (a multiple of the device count) is the
    batch; it returns NumPy arrays, gathered from every process when running multi-host.
    Calling it again with the same shapes does not recompile.

    Attributes:
        mesh: the 1-D device mesh (axis ``"batch"``).
        jitted: the jitted, sharded ``vmap(render_fn)``.
    """

    mesh: Mesh
    jitted: Any

    def __call__(self, params):
        n = batch_size(params)
        if n % self.mesh.devices.size:
            raise ValueError(
                f"batch of {n} items is not a multiple of the {self.mesh.devices.size} devices"
            )
        return _run(self.jitted, params, self.mesh)


def sharded_renderer(render_fn: Callable, devices=None) -> ShardedRenderer:
    """Jits ``vmap(render_fn)`` once, sharded over a 1-D device mesh.

    Args:
        render_fn: function of ONE item (e.g. one camera) returning a pytree.
        devices: devices to shard over (default: all devices of all processes).

    Returns:
        A :class:`ShardedRenderer`: ``params -> outputs`` for a batch of items.
    """
    mesh = device_mesh(devices)
    batch_sharding = NamedSharding(mesh, PartitionSpec("batch"))
    return ShardedRenderer(
        mesh,
        jax.jit(
            _per_device(render_fn, mesh), in_shardings=batch_sharding, out_shardings=batch_sharding
        ),
    )


def _per_device(render_fn: Callable, mesh: Mesh) -> Callable:
    """``vmap(render_fn)`` run by each device on its own slice of the batch (``shard_map``).

    ``render_fn`` may be any function of one item; inside ``shard_map`` each device sees
    only its own items, so the partitioner never has to split a user's loops.
    """
    spec = PartitionSpec(BATCH_AXIS)
    return shard(jax.vmap(render_fn), mesh, spec, spec)


@dataclasses.dataclass(frozen=True)
class ShardedMap:
    """``jit(vmap(fn, in_axes))`` over a 1-D device mesh; see :func:`sharded_vmap`.

    Attributes:
        mesh: the 1-D device mesh (axis ``"batch"``).
        in_axes: 0 or None per positional argument.
        jitted: the jitted, sharded ``vmap(fn)``.
    """

    mesh: Mesh
    in_axes: tuple
    jitted: Any

    def replicate(self, tree):
        """Put ``tree`` on every device once (shared data), so calls do not copy it again."""
        return jax.device_put(tree, NamedSharding(self.mesh, PartitionSpec()))

    def split(self, tree):
        """Put ``tree`` (leading axis a multiple of the devices) split over the devices."""
        return jax.device_put(tree, NamedSharding(self.mesh, PartitionSpec("batch")))

    def __call__(self, *args):
        if len(args) != len(self.in_axes):
            raise TypeError(f"in_axes has {len(self.in_axes)} entries for {len(args)} arguments")
        n = batch_size([x for x, a in zip(args, self.in_axes) if a == 0])
        pad = -n % int(self.mesh.devices.size)
        if pad:
            # repeat the last item: the padded rows are computed and dropped
            grow = (
                lambda x: jax.numpy.concatenate(  # noqa: E731
                    [x, jax.numpy.repeat(x[-1:], pad, axis=0)]
                )
            )
            args = tuple(
                jax.tree_util.tree_map(grow, x) if a == 0 else x for x, a in zip(args, self.in_axes)
            )
        out = self.jitted(*args)
        return jax.tree_util.tree_map(lambda y: y[:n], out) if pad else out


def sharded_vmap(fn: Callable, in_axes, devices=None, *, chunk: int | None = None) -> ShardedMap:
    """``jit(vmap(fn, in_axes))`` with the batch split over a 1-D device mesh; arrays back.

    The in-memory sibling of :func:`sharded_renderer` for per-item kernels with shared data (a
    mesh's binding) that must not be copied per item: arguments with ``in_axes`` 0 are split
    along their leading axis over the devices, arguments with ``None`` are replicated.  With
    one host device per core (``--xla_force_host_platform_device_count``, set before JAX
    starts) it runs one shard per core, e.g. a batch of poses through
    :func:`jaxgfx.skin.linear_blend_skinning` on every core::

        lbs = sharded_vmap(skin.linear_blend_skinning, (0, None, None, None, None), chunk=8)
        mesh = lbs.replicate((vertices, normals, joints, weights))  # once
        pos, nrm = lbs(transforms, *mesh)  # transforms (B, J, 3, 4) -> (B, V, 3) twice

    ``chunk`` runs each device's shard as ``lax.map(fn, batch_size=chunk)``: ``chunk`` items
    vmapped at a time, in a loop.  Table lookups (skinning's bone matrices) then stay in the
    core's cache (``python -m experiments.skinning_bench`` compares chunks with one vmap).
    A batch that is not a multiple of the
    device count is padded with its last item and the outputs are cut back (one extra copy).
    Calls with the same shapes do not recompile.

    Args:
        fn: function of ONE item.
        in_axes: a tuple with 0 (batched) or None (shared) per positional argument.
        devices: devices to shard over (default: all devices).
        chunk: items per step of each device's loop (default: the whole shard in one vmap).

    Returns:
        A :class:`ShardedMap`: ``(*args) -> outputs`` with a leading batch axis.
    """
    if not isinstance(in_axes, (tuple, list)) or not all(a in (0, None) for a in in_axes):
        raise ValueError(f"in_axes must be a tuple of 0 or None per argument, got {in_axes!r}")
    if 0 not in in_axes:
        raise ValueError("in_axes: at least one argument must be batched (0)")
    if chunk is not None:
        chunk = check_int("chunk", chunk, low=1)
    axes = tuple(in_axes)
    mesh = device_mesh(devices)

    def local(*args):
        if chunk is None:
            return jax.vmap(fn, in_axes=axes)(*args)
        batched = [x for x, a in zip(args, axes) if a == 0]

        def one(items):
            it = iter(items)
            return fn(*(next(it) if a == 0 else x for x, a in zip(args, axes)))

        return jax.lax.map(one, batched, batch_size=chunk)

    spec = tuple(PartitionSpec(BATCH_AXIS) if a == 0 else PartitionSpec() for a in axes)
    jitted = jax.jit(
        shard(local, mesh, spec, PartitionSpec(BATCH_AXIS)),
        in_shardings=tuple(NamedSharding(mesh, sp) for sp in spec),
    )
    return ShardedMap(mesh, axes, jitted)


def _spans_processes(mesh: Mesh) -> bool:
    """True when ``mesh`` holds devices of more than one process (multi-host)."""
    return len({d.process_index for d in mesh.devices.flat}) > 1


def _run(fn, params, mesh):
    batch_sharding = NamedSharding(mesh, PartitionSpec("batch"))

    def put(x):
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, batch_sharding, lambda idx: x[idx])

    out = fn(jax.tree_util.tree_map(put, params))
    # Only a mesh over several processes leaves shards this process cannot read; a sweep over
    # this process's own devices (in a multi-process run) must not wait on the others.
    if _spans_processes(mesh):
        from jax.experimental import multihost_utils

        out = multihost_utils.process_allgather(out, tiled=True)
    return jax.tree_util.tree_map(np.asarray, out)


def _fingerprint(params, chunk_size: int) -> str:
    h = hashlib.sha256()
    h.update(str(chunk_size).encode())
    for leaf in jax.tree_util.tree_leaves(params):
        a = np.ascontiguousarray(np.asarray(leaf))
        h.update(str(a.shape).encode() + str(a.dtype).encode())
        h.update(a.tobytes())
    h.update(str(jax.tree_util.tree_structure(params)).encode())
    return h.hexdigest()[:16]


def render_fingerprint(render_fn: Callable, chunk_params) -> dict:
    """What defines a sweep's output besides its parameters: the computation and its outputs.

    ``jax.jit(jax.vmap(render_fn))`` is lowered (not compiled) for one chunk's parameters and
    its StableHLO text, without source locations, is hashed.  Constants the function closes
    over (a mesh, a colour, a light) are printed in full into that text, so changing any of
    them, or the code, changes the hash; the text has no addresses or ids, so the hash is the
    same in every process.  It does depend on the JAX version and the backend (lowering
    rules are per platform).

    Args:
        render_fn: ``item -> pytree`` for ONE item.
        chunk_params: one chunk's parameters, leading axis = the chunk size.

    Returns:
        ``{"function": 16 hex digits, "outputs": {"name": "dtype[shape]", ...}}``; the
        output shapes include the chunk axis.
    """
    return _lowered_fingerprint(render_fn, chunk_params)[0]


def _lowered_fingerprint(render_fn: Callable, chunk_params) -> tuple[dict, Any]:
    """:func:`render_fingerprint` and the lowered computation's output avals."""
    lowered = jax.jit(jax.vmap(render_fn)).lower(chunk_params)
    text = lowered.as_text(debug_info=False)
    paths_avals = jax.tree_util.tree_flatten_with_path(lowered.out_info)[0]
    outputs = {
        jax.tree_util.keystr(path) or "out": f"{a.dtype}{list(a.shape)}" for path, a in paths_avals
    }
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    return {"function": digest, "outputs": outputs}, lowered.out_info


_PARTS = {
    "n": "the number of items",
    "chunk_size": "the chunk size (after rounding to the device count)",
    "n_chunks": "the number of chunks",
    "params": "the per-item parameters",
    "function": "the render function (its code, a constant it closes over, the JAX version "
    "or the backend)",
    "outputs": "the output names, shapes or dtypes",
    "version": "the version string",
    "images": "the outputs stored as PNG images, or their file names",
    "fingerprint": "the manifest's format (written by an older jaxgfx)",
}


class SweepMismatch(ValueError):
    """``out_dir`` holds a different sweep; ``parts`` describes each part that differs."""

    def __init__(self, out_dir: Path, parts: str) -> None:
        self.out_dir = out_dir
        self.parts = parts
        super().__init__(
            f"out_dir {out_dir} holds a different sweep, so its chunks cannot be reused: "
            f"{parts}. To start over, delete {out_dir} or pass a new out_dir (to keep the old "
            "chunks, undo the change)"
        )


def _check_manifest(out_dir: Path, old: dict, new: dict) -> None:
    """Raises :class:`SweepMismatch` naming every part in which ``out_dir``'s sweep differs."""
    keys = sorted(set(old) | set(new), key=lambda k: list(_PARTS).index(k) if k in _PARTS else 99)
    diff = [k for k in keys if old.get(k) != new.get(k)]
    if diff:
        raise SweepMismatch(
            out_dir,
            "; ".join(
                f"{_PARTS.get(k, k)} ({k}: on disk {old.get(k)!r}, now {new.get(k)!r})"
                for k in diff
            ),
        )


def _writes(mesh: Mesh) -> bool:
    """Whether this process reads and writes the sweep's files: process 0 of a multi-process
    mesh, or the one process of a mesh over its own devices."""
    return jax.process_index() == 0 or not _spans_processes(mesh)


def _decide(out_dir: Path, manifest: dict, sizes: list[int], mesh: Mesh) -> list[bool]:
    """Checks ``out_dir``'s manifest and returns which chunks are done, as process 0 sees it.

    Process 0 alone reads ``out_dir`` and, when ``mesh`` spans several processes, broadcasts
    what it found, so every process computes the same chunks (the sharded program and the
    gather need all of them) even where the others see another disk or none.

    Raises:
        SweepMismatch: on every process, when process 0's ``out_dir`` holds another sweep.
    """
    mpath = out_dir / "manifest.json"
    error: SweepMismatch | None = None
    done = [False] * len(sizes)
    if _writes(mesh):
        try:
            if mpath.exists():
                _check_manifest(out_dir, json.loads(mpath.read_text()), manifest)
            else:
                save_json(mpath, manifest)
            done = [chunk_complete(out_dir, k, sizes, manifest) for k in range(len(sizes))]
        except SweepMismatch as exc:
            error = exc
    if _spans_processes(mesh):
        from jax.experimental import multihost_utils

        state = np.asarray([error is not None, *done], np.int32)
        state = np.asarray(multihost_utils.broadcast_one_to_all(state))
        if error is None and state[0]:
            error = SweepMismatch(
                out_dir, "process 0 found a different sweep there (its error names the parts)"
            )
        done = [bool(x) for x in state[1:]]
    if error is not None:
        raise error
    return done


def run_sweep(
    render_fn: Callable,
    params,
    out_dir,
    chunk_size: int = 8,
    devices=None,
    progress: bool = True,
    on_chunk: Callable | None = None,
    version: str | None = None,
    images: Sequence[str] | Mapping[str, str] = (),
) -> dict:
    """Renders every item of ``params`` in chunks, resumably.

    Args:
        render_fn: ``item -> dict[str, array]`` for ONE item (e.g. one camera);
            it is vmapped and jitted here, once per sweep.
        params: pytree whose leaves share a leading axis of N items.
        out_dir: directory for ``manifest.json`` and ``chunk_XXXXX.npz``.
        chunk_size: items per chunk; rounded up to a multiple of the device count.
        devices: devices to shard over (default all, i.e. all hosts' devices).
        progress: show a tqdm progress bar.
        on_chunk: optional ``callback(k, start, outputs)`` called after chunk k
            is on disk (e.g. to write per-frame PNGs); also called for chunks
            found on disk, so derived files are completed on resume.  With several
            processes it runs on process 0 only (the one that writes the chunks).
        version: optional label of what ``render_fn`` means (e.g. ``"shading v3"``); stored
            in the manifest and compared on resume, for changes the lowered computation
            cannot see (e.g. an ``on_chunk`` that writes other files).
        images: outputs stored as one PNG per item instead of inside the chunk's
            ``.npz``: uint8 ``(H, W)`` or ``(H, W, 3|4)`` per item (e.g. a colour frame
            through :func:`jaxgfx.compose.to_uint8`).  A sequence of output names stores
            ``NAME_{i:05d}.png`` in ``out_dir``; a mapping gives each name its file
            pattern, formatted with the item index ``i`` and taken relative to
            ``out_dir`` (e.g. ``{"color": "../frame_{i:05d}.png"}``).  PNG is lossless:
            :func:`load_sweep` returns the same arrays.

    A sweep started again into the same ``out_dir`` reuses the chunks on disk only when
    everything that defines them is unchanged: the parameters, the chunking, the render
    function (a hash of ``jax.jit(jax.vmap(render_fn))`` lowered for one chunk, see
    :func:`render_fingerprint`), the output names, shapes and dtypes, ``version`` and
    ``images``.  Chunks are stored compressed (``np.savez_compressed``); an interrupted
    write leaves no partial file (:func:`jaxgfx.io.atomic_write`), so a chunk on disk is
    always whole.

    Returns:
        Summary dict: ``{"n", "chunks", "computed", "skipped", "devices", "out_dir"}``.

    Raises:
        SweepMismatch: (a ValueError) ``out_dir`` holds a different sweep; the message
            names each part that differs (params, chunking, function, outputs, version).
            Nothing is written.
        TypeError: ``render_fn`` does not return a dict of arrays, or ``version`` is not a str.
        ValueError: ``images`` names an output that is missing or not 8-bit images.
    """
    chunk_size = check_int("chunk_size", chunk_size, low=1)
    if version is not None and not isinstance(version, str):
        raise TypeError(f"version must be a str or None, got {type(version).__name__}")
    n = batch_size(params)
    mesh = device_mesh(devices)
    ndev = mesh.devices.size
    chunk_size = -(-chunk_size // ndev) * ndev
    n_chunks = -(-n // chunk_size)
    out_dir = Path(out_dir)
    # Lowering (no compile) for one chunk: the function's fingerprint, and a bad return type
    # is reported before anything is computed or written.
    defines, out_info = _lowered_fingerprint(render_fn, _slice(params, 0, 1, chunk_size))
    if not isinstance(out_info, dict):
        raise TypeError("render_fn must return a dict of arrays")
    patterns = image_patterns(images)
    check_image_outputs(patterns, out_info)
    manifest = {
        "n": n,
        "chunk_size": chunk_size,
        "n_chunks": n_chunks,
        "params": _fingerprint(params, chunk_size),
        **defines,
        "version": version,
    }
    if patterns:  # absent when unused: manifests of sweeps without images stay as they were
        manifest["images"] = patterns
    out_dir.mkdir(parents=True, exist_ok=True)
    sizes = [min(n, (k + 1) * chunk_size) - k * chunk_size for k in range(n_chunks)]
    done = _decide(out_dir, manifest, sizes, mesh)
    writer = _writes(mesh)
    fn = jax.jit(
        _per_device(render_fn, mesh),
        in_shardings=NamedSharding(mesh, PartitionSpec("batch")),
        out_shardings=NamedSharding(mesh, PartitionSpec("batch")),
    )
    computed = skipped = 0
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n_chunks, desc="sweep", unit="chunk")
    try:
        for k in range(n_chunks):
            start, stop = k * chunk_size, min(n, (k + 1) * chunk_size)
            path = chunk_path(out_dir, k)
            if done[k]:
                skipped += 1
                if on_chunk is not None and writer:
                    with np.load(path) as z:
                        found = {key: z[key] for key in z.files}
                    found.update(read_images(out_dir, patterns, start, stop - start))
                    on_chunk(k, start, found)
            else:
                out = _run(fn, _slice(params, start, stop, chunk_size), mesh)
                out = {key: v[: stop - start] for key, v in out.items()}
                if writer:
                    write_chunk(out_dir, k, start, out, patterns)
                computed += 1
                if on_chunk is not None and writer:
                    on_chunk(k, start, out)
            if bar is not None:
                bar.update(1)
    finally:  # also on Ctrl-C: the bar's last line comes before the caller's message
        if bar is not None:
            bar.close()
    return {
        "n": n,
        "chunks": n_chunks,
        "computed": computed,
        "skipped": skipped,
        "devices": ndev,
        "out_dir": str(out_dir),
    }
