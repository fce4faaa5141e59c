"""One frame's z-buffer split over several devices (every host core for one frame).

XLA:CPU runs one computation on one core; Mesa llvmpipe draws one frame with a thread
per core.  :func:`split_visible_faces` gives each of D devices (host devices on a CPU:
``--xla_force_host_platform_device_count`` or ``jax_num_cpu_devices``) every D-th face of
the mesh; each z-buffers its faces over the whole frame, and the D buffers are merged
with the z-buffer's own rule through two collectives: the largest 1/z bits (``pmax``),
then, among the devices holding that exact value, the smallest face index (``pmin``).
Within a device the same rule already holds, so the merged frame is bit-identical to one
device's, whatever D.

Faces are dealt out interleaved (face ``i`` to device ``i % D``), not in contiguous
blocks: a mesh's cost is rarely uniform along its face order (a heightfield's rows near
the camera have 10x the tiles of far ones), and interleaving balances it.

It is opt-in (``rasterize(..., devices=D)``), not automatic: a split frame is an SPMD
program over D devices, which a user's own ``pmap``/``shard_map`` (or the sweep's, which
already gives each device its own frames) must not nest.  Under ``jax.vmap`` the split is
dropped (``custom_vmap``): the batch goes to :func:`jaxgfx._src.zbuffer.visible_faces`,
whose rule keeps the frames of a batch whole, so a batch is never split twice.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec

from jaxgfx._src.camera import world_to_camera_soa
from jaxgfx._src.frames import batch_mesh, shard
from jaxgfx._src.zbuffer import NO_TRI, _frame_visibility, visible_faces

__all__ = ["split_visible_faces", "resolve_devices"]

_AXIS = "faces"


def resolve_devices(devices) -> tuple:
    """The devices of ``rasterize(devices=)``: an int D (the first D of ``jax.devices()``)
    or a sequence of devices; raises ``ValueError``/``TypeError`` naming ``devices``."""
    if isinstance(devices, bool):
        raise TypeError(f"devices must be an int or a sequence of devices, got {devices!r}")
    avail = jax.devices()
    if isinstance(devices, (int, np.integer)):
        if not 1 <= devices <= len(avail):
            raise ValueError(
                f"devices must be between 1 and the {len(avail)} available devices, got {devices}"
            )
        return tuple(avail[: int(devices)])
    try:
        devs = tuple(devices)
    except TypeError:
        raise TypeError(
            f"devices must be an int or a sequence of devices, got {type(devices).__name__}"
        ) from None
    if not devs or not all(isinstance(d, jax.Device) for d in devs):
        raise ValueError("devices must be a non-empty sequence of jax devices")
    if len(set(devs)) != len(devs):
        raise ValueError("devices must not repeat a device")
    return devs


@functools.cache
def _split_fn(
    devices: tuple, cull_backfaces: bool, block: int, chunk: int, tri_batch: int, batching: str
):
    """The split kernel for one static configuration (built once, cached)."""
    d = len(devices)
    static = dict(cull_backfaces=cull_backfaces, block=block, chunk=chunk, tri_batch=tri_batch)

    def local(cam, vertices, faces):
        k = jax.lax.axis_index(_AXIS)
        p_cam = world_to_camera_soa(cam, vertices)
        inv_depth, fid = _frame_visibility(
            cam, vertices, p_cam, faces, cull_backfaces, block, chunk, tri_batch
        )
        zbits = jax.lax.bitcast_convert_type(inv_depth, jnp.int32)
        # Local face i of device k is face i * d + k of the mesh (interleaved deal).
        fid = jnp.where(fid != NO_TRI, fid * d + k, NO_TRI)
        zmax = jax.lax.pmax(zbits, _AXIS)
        fid = jax.lax.pmin(jnp.where(zbits == zmax, fid, NO_TRI), _AXIS)
        return jax.lax.bitcast_convert_type(zmax, jnp.float32), fid

    split = shard(
        local,
        batch_mesh(devices, _AXIS),
        (PartitionSpec(), PartitionSpec(), PartitionSpec(_AXIS)),
        (PartitionSpec(), PartitionSpec()),
    )

    @jax.custom_batching.custom_vmap
    def kernel(cam, vertices, faces):
        f = faces.shape[0]
        per = -(-f // d)
        if per * d != f:  # degenerate padding faces: zero area, never drawn
            faces = jnp.concatenate([faces, jnp.zeros((per * d - f, 3), faces.dtype)])
        # Device-major blocks of the interleaved deal: block k holds faces k, k+d, ...
        dealt = faces.reshape(per, d, 3).transpose(1, 0, 2).reshape(per * d, 3)
        return split(cam, vertices, dealt)

    @kernel.def_vmap
    def whole_frames(axis_size, in_batched, cam, vertices, faces):
        # A batch keeps its frames whole (visible_faces and its own batching rule), never
        # split twice: the batch is placed by its own sharding.
        del axis_size
        axes = [jax.tree_util.tree_map(lambda b: 0 if b else None, a) for a in in_batched]
        out = jax.vmap(
            lambda c, v, f: visible_faces(c, v, f, batching=batching, **static), in_axes=axes
        )(cam, vertices, faces)
        return out, (True, True)

    return kernel


def split_visible_faces(
    cam,
    vertices: jax.Array,
    faces: jax.Array,
    devices: tuple,
    *,
    cull_backfaces: bool,
    block: int,
    chunk: int,
    tri_batch: int,
    batching: str = "auto",
) -> tuple[jax.Array, jax.Array]:
    """Nearest face per pixel of ONE frame, its faces split over ``devices``.

    Args:
        cam: one camera (static resolution).
        vertices: (V, 3) world positions.
        faces: (F, 3) int32 vertex indices.
        devices: the devices, from :func:`resolve_devices` (static).
        cull_backfaces, block, chunk, tri_batch, batching: as in
            :func:`jaxgfx._src.zbuffer.visible_faces` (static).

    Returns:
        ``(inv_depth, face_id)``, each (H*W,), bit-identical to ``visible_faces``.
    """
    fn = _split_fn(
        tuple(devices), bool(cull_backfaces), int(block), int(chunk), int(tri_batch), batching
    )
    return fn(cam, vertices, faces)
