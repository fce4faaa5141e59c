"""The exact per-pixel reference renderer: a 3-D DDA through the dense grid.

Slow and exact; :func:`jaxgfx.raycast.render_rle` is measured against it (depth within
one voxel on >= 99 % and the same colour on >= 98 % of pixels).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxgfx._src.camera import Camera, pixel_rays
from jaxgfx._src.voxel.grid import _dda_entry
from jaxgfx._src.voxel.render import RenderOutput

__all__ = ["dda_ray_3d", "reference_render"]


def dda_ray_3d(occupancy, colors, origin, direction, *, max_steps: int, far):
    """First solid voxel along ONE ray by an exact 3-D DDA (Amanatides & Woo).

    Args:
        occupancy: (X, Y, Z) bool grid.
        colors: (X, Y, Z, 3) uint8.
        origin: (3,) ray origin.
        direction: (3,) direction; the returned ``t`` is in its units.
        max_steps: static ``lax.scan`` length (``X + Y + Z`` suffices).
        far: () largest accepted t.

    Returns:
        ``(rgb (3,) float32, t () float32 (+inf on a miss), voxel (3,) int32 (-1 on a miss))``.
    """
    inv, t_enter, t_exit, idx, step, tiny = _dda_entry(occupancy.shape, origin, direction, 0.0)
    dmax = jnp.asarray(occupancy.shape, jnp.int32) - 1

    def body(carry, _):
        idx, t, done, hit = carry
        solid = occupancy[idx[0], idx[1], idx[2]]
        found = ~done & solid & (t <= far)
        nxt = ((idx + (direction > 0)).astype(jnp.float32) - origin) * inv
        nxt = jnp.where(tiny, jnp.inf, nxt)
        ax = jnp.argmin(nxt)
        t_n = nxt[ax]
        idx_n = idx.at[ax].add(step[ax])
        out = jnp.any(idx_n < 0) | jnp.any(idx_n > dmax) | (t_n > far)
        done_n = done | found | out
        hit = hit | found
        idx = jnp.where(done_n, idx, idx_n)
        t = jnp.where(done_n, t, t_n)
        return (idx, t, done_n, hit), None

    done0 = t_enter > t_exit
    (idx, t, done, hit), _ = jax.lax.scan(
        body, (idx, t_enter, done0, jnp.bool_(False)), None, length=max_steps
    )
    rgb = colors[idx[0], idx[1], idx[2]].astype(jnp.float32) / 255.0
    return (
        jnp.where(hit, rgb, 0.0),
        jnp.where(hit, t, jnp.inf),
        jnp.where(hit, idx, -1),
    )


def reference_render(occupancy, colors, cam: Camera, *, max_steps: int | None = None):
    """Per-pixel 3-D DDA renderer through a dense grid (slow, exact); same camera.

    jit with ``static_argnames=("max_steps",)``.

    Args:
        occupancy: (X, Y, Z) bool.
        colors: (X, Y, Z, 3) uint8.
        cam: camera.
        max_steps: static DDA length (default ``X + Y + Z + 3``).

    Returns:
        ``(RenderOutput(color (H, W, 3), depth (H, W), {}), voxel (H, W, 3) int32)``.
    """
    if max_steps is None:
        max_steps = int(sum(occupancy.shape)) + 3
    origins, dirs = pixel_rays(cam, normalize=False)
    fn = lambda o, d: dda_ray_3d(occupancy, colors, o, d, max_steps=max_steps, far=cam.far)  # noqa: E731
    rgb, t, vox = jax.vmap(jax.vmap(fn))(origins, dirs)
    return RenderOutput(rgb, t, {}), vox
