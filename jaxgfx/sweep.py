"""Batched, sharded, resumable rendering sweeps.

:func:`run_sweep` renders a pytree of per-item parameters in fixed-size chunks, each
``jax.vmap``-ped and sharded over a 1-D device mesh, writes every finished chunk
atomically and continues where it stopped when run again; :func:`load_sweep` reads the
result.  :func:`shard_batch` places a batch over every local device (one host device per
core on a CPU), so that ``jax.jit(jax.vmap(f))`` runs each device's items there.  With
``jax.distributed.initialize()`` on every host the mesh spans every host's
devices and process 0 writes the files.
"""

from __future__ import annotations

from jaxgfx._src.frames import shard_batch as shard_batch
from jaxgfx._src.sweep import ShardedMap as ShardedMap
from jaxgfx._src.sweep import ShardedRenderer as ShardedRenderer
from jaxgfx._src.sweep import SweepMismatch as SweepMismatch
from jaxgfx._src.sweep import batch_size as batch_size
from jaxgfx._src.sweep import chunk_path as chunk_path
from jaxgfx._src.sweep import device_mesh as device_mesh
from jaxgfx._src.sweep import image_path as image_path
from jaxgfx._src.sweep import load_sweep as load_sweep
from jaxgfx._src.sweep import render_fingerprint as render_fingerprint
from jaxgfx._src.sweep import run_sweep as run_sweep
from jaxgfx._src.sweep import sharded_renderer as sharded_renderer
from jaxgfx._src.sweep import sharded_vmap as sharded_vmap

__all__ = [
    "shard_batch",
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
