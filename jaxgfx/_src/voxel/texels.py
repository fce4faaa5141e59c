"""The ray buffer's texels resolved: :func:`traverse_planes` (thesis 4.5.4.4).

:func:`~jaxgfx.raycast.traverse_lists` leaves each plane's drawn elements as a
front-to-back list; here a coverage tree per plane names every texel's first
(nearest) writer, the ray buffer as the thesis draws it, for
:func:`~jaxgfx.raycast.warp_ray_buffer` and for inspection.  The renderer skips
this step: its warp (:func:`~jaxgfx.raycast.warp_lists`) scans the lists of the
texels that covered pixels read.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera
from jaxgfx._src.voxel.codec import WORD_ROWS, unpack_drawn_rows
from jaxgfx._src.voxel.planes import Segments
from jaxgfx._src.voxel.traverse import traverse_lists

__all__ = ["traverse_planes", "traverse_plane"]

_INF_KEY = np.int32(2**31 - 1)


# ---------------------------------------------------------------------------
# 4.5.4.4 Coverage tree: the nearest writer of every texel
# ---------------------------------------------------------------------------


def _coverage_tree(r0, r1, used, n_tree, depth_levels):
    """Per-pixel coverage: a segment tree holding the minimum key over row intervals.

    Each interval ``[r0, r1)`` is split into O(log R) tree nodes; a row's writer
    is the minimum key on its path to the root.  Keys (list indices) grow front to back, so the
    minimum is the nearest element: every pixel is drawn once (4.5.4.3).
    """
    key = jnp.arange(r0.shape[0], dtype=jnp.int32)
    lpos = jnp.where(used, r0, 0) + n_tree
    rpos = jnp.where(used, r1, 0) + n_tree
    idxs = []
    for _ in range(depth_levels):
        take_l = (lpos < rpos) & ((lpos & 1) == 1)
        idxs.append(jnp.where(take_l, lpos, 2 * n_tree))
        lpos = jnp.where(take_l, lpos + 1, lpos)
        take_r = (lpos < rpos) & ((rpos & 1) == 1)
        rpos = jnp.where(take_r, rpos - 1, rpos)
        idxs.append(jnp.where(take_r, rpos, 2 * n_tree))
        lpos = lpos >> 1
        rpos = rpos >> 1
    idx = jnp.concatenate(idxs)
    keys = jnp.tile(key, 2 * depth_levels)
    tree = jnp.full((2 * n_tree,), _INF_KEY, jnp.int32)
    return tree.at[idx].min(keys, mode="drop")


def _texel_entries(trees):
    """(P, n) int32 nearest element of every ray-buffer texel: min over the tree path.

    Level ``lv`` of the tree is the contiguous slice ``[n >> lv, 2n >> lv)``;
    repeating it ``2 ** lv`` times lines it up with the leaves (a broadcast,
    which XLA:CPU runs far faster than the equivalent gather).
    """
    P, n_tree = trees.shape[0], trees.shape[1] // 2
    entry = trees[:, n_tree:]
    for lv in range(1, int(math.log2(n_tree)) + 1):
        level = trees[:, n_tree >> lv : (2 * n_tree) >> lv]
        up = jnp.broadcast_to(level[:, :, None], (P, n_tree >> lv, 1 << lv))
        entry = jnp.minimum(entry, up.reshape(P, n_tree))
    return entry


def traverse_planes(rle, cam: Camera, seg: Segments, planes: jax.Array, **kw):
    """Renders a batch of planes into their ray-buffer columns (4.5.4).

    :func:`traverse_lists` and the resolved texels: a coverage tree per plane
    names every texel's first (nearest) writer (the renderer itself skips this:
    its warp scans the lists of the covered pixels only).  Takes the keyword
    arguments of :func:`traverse_lists`.

    Returns:
        ``(texels (P, n) int32, elements (P, 5, K) int32, stats (P, 4) int32)``:
        the index of each row's nearest drawn element (``>= K`` where none;
        ``n`` = ``rows`` rounded up to a power of two) and the lists and counts
        of :func:`traverse_lists`.
    """
    pool, start, nbuf, _, _, stats = traverse_lists(rle, cam, seg, planes, **kw)
    rows = kw["rows"]
    K = -(-(kw.get("buffer_size") or max(64, rows // 2)) // 8) * 8  # as traverse_lists
    # Each plane's list in its own K slots (zeros past its end), as before the pool.
    j = jnp.arange(K, dtype=jnp.int32)[None, :]
    idx = jnp.clip(start[:, None] + j, 0, pool.shape[1] - 1)
    elements = jnp.where((j < nbuf[:, None])[:, None, :], jnp.moveaxis(pool[:, idx], 0, 1), 0)
    n_tree = 1 << max(1, math.ceil(math.log2(rows)))
    depth_levels = int(math.log2(n_tree)) + 1

    def resolve(k):
        def fn(ibuf, nbuf):
            used = jnp.arange(k)[None, :] < nbuf[:, None]
            trees = jax.vmap(
                lambda b, u: _coverage_tree(
                    *unpack_drawn_rows(b[WORD_ROWS]), u, n_tree, depth_levels
                )
            )(ibuf[:, :, :k], used)
            return _texel_entries(trees)

        return fn

    # The tree costs O(list length) per plane: only the longest list's prefix is used.
    tiers = sorted({t for t in (16, 32, 64, 128, 256) if t < K} | {K})
    tier = jnp.minimum(
        jnp.searchsorted(jnp.asarray(tiers, jnp.int32), jnp.max(nbuf)), len(tiers) - 1
    )
    texels = jax.lax.switch(tier, [resolve(t) for t in tiers], elements, nbuf)
    return texels, elements, stats


def traverse_plane(
    rle,
    cam: Camera,
    seg: Segments,
    plane: jax.Array,
    *,
    rows: int,
    max_steps: int,
    lod_distance: jax.Array,
    buffer_size: int | None = None,
    elements_per_step: int = 4,
):
    """Renders ONE plane (4.5.4): :func:`traverse_planes` for a batch of one.

    Returns:
        ``(texels (n,) int32, elements (5, K) int32, stats (4,) int32)``.
    """
    out = traverse_planes(
        rle,
        cam,
        seg,
        jnp.asarray(plane, jnp.int32)[None],
        rows=rows,
        max_steps=max_steps,
        lod_distance=lod_distance,
        buffer_size=buffer_size,
        elements_per_step=elements_per_step,
    )
    return jax.tree_util.tree_map(lambda x: x[0], out)
