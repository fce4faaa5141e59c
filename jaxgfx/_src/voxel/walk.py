"""The per-plane walk of the ray caster: its start, its cells and its culling bounds (4.5.4).

What the wide traversal (:mod:`.wide`) and the scatter's plane tables
(:mod:`.scatter_planes`) share: each plane's constants and starting state
(:func:`_plane_init`: its x-z direction, Eq. 4.5's terms, its entry into the map),
the exact 2-D DDA's cell exit (:func:`_cell_exit`), an element's slopes and rows
over a cell (:func:`_slopes`, :func:`_rows_of`), the front-to-back order of a
column's elements (:func:`_unrank`), and a bound that lets a plane stop without
changing what it draws (not in the thesis): the rows whose rays can still meet
the scene (:func:`_live_rows`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxgfx._src.camera import Camera, camera_basis, focal_lengths
from jaxgfx._src.voxel.codec import NO_ENTRY
from jaxgfx._src.voxel.grid import _safe_div
from jaxgfx._src.voxel.planes import Segments, plane_extent

__all__: list[str] = []  # private helpers of wide.py and scatter_planes.py

_TINY = 1e-6


# ---------------------------------------------------------------------------
# Coverage rows (4.5.4.3), rows that can still meet the scene
# ---------------------------------------------------------------------------


def _row_mask(r0, r1, n_words):
    """(N, n_words) uint32 bit masks of the row ranges ``[r0, r1)``."""
    w = 32 * jnp.arange(n_words, dtype=jnp.int32)[None, :]
    a = jnp.clip(r0[:, None] - w, 0, 32).astype(jnp.uint32)
    b = jnp.clip(r1[:, None] - w, 0, 32).astype(jnp.uint32)
    full = jnp.uint32(0xFFFFFFFF)
    low = lambda n: jnp.where(n >= 32, full, (jnp.uint32(1) << jnp.minimum(n, 31)) - 1)  # noqa: E731
    return jnp.where(b > a, low(b) & ~low(a), jnp.uint32(0))


def _once(x):
    """``x`` (int32 or bool), computed once for all of its users; the same values.

    XLA:CPU fuses cheap element-wise producers into every consumer, so a value
    read by several fused ops (an element's rows by the coverage test, the
    coverage update, the floating horizon and the list slots) is recomputed in
    each, from the element's projection on.  A reduce is never fused into more
    than one consumer: a ``min`` with the type's largest value pins ``x`` in
    memory.
    """
    top = True if x.dtype == jnp.bool_ else jnp.iinfo(x.dtype).max
    return jnp.min(jnp.stack([x, jnp.full_like(x, top)], axis=-1), axis=-1)


def _scene_top(rle) -> float:
    """Highest y any element of any mip level reaches (a coarse cube-mip level rounds Y up)."""
    return float(
        max(s[1] << (0 if rle.column_mips else lev) for lev, s in enumerate(rle.level_shapes))
    )


def _slopes(consts, y_lo, y_hi, ey, inv_in, inv_out):
    """Slopes ``(s_min, s_max)`` under which heights ``[y_lo, y_hi]`` are seen over a cell.

    The cell spans horizontal distances ``1 / inv_in`` to ``1 / inv_out`` along the
    plane; the extreme slopes are at its corners, clipped to the plane's visible
    slopes (Eq. 4.5's input).  ``s_min > s_max``: not visible.
    """
    c0, c1 = (y_lo - ey) * inv_in, (y_hi - ey) * inv_in
    c2, c3 = (y_lo - ey) * inv_out, (y_hi - ey) * inv_out
    s_min = jnp.maximum(jnp.minimum(jnp.minimum(c0, c1), jnp.minimum(c2, c3)), consts.s_min)
    s_max = jnp.minimum(jnp.maximum(jnp.maximum(c0, c1), jnp.maximum(c2, c3)), consts.s_max)
    return s_min, s_max


def _project(consts, s, fy):
    """Ray-buffer coordinate of slope ``s`` in one plane (Eq. 4.5)."""
    return (consts.p_num + consts.q_num * s) / jnp.maximum(consts.hf + s * fy, 1e-9)


def _rows_of(consts, s_a, s_b, fy, margin=0.0):
    """Rows ``[r0, r1)`` of one plane seen under slopes between ``s_a`` and ``s_b`` (Eq. 4.5).

    The rows whose centres lie between the two slopes' ray-buffer coordinates,
    widened by ``margin`` rows on each side.
    """
    a, b = _project(consts, s_a, fy), _project(consts, s_b, fy)
    r0 = jnp.ceil(jnp.minimum(a, b) - 0.5 - margin).astype(jnp.int32)
    r1 = jnp.floor(jnp.maximum(a, b) - 0.5 + margin).astype(jnp.int32) + 1
    return r0, r1


def _live_rows(consts, ey, t, *, y_top: float, fy):
    """Rows ``[a0, a1)`` of one plane whose rays still meet ``0 <= y <= y_top`` past ``t``.

    Along the plane a row's ray is ``y = ey + s t'`` (``s``: its slope), for
    ``t <= t' <= t_far``; it meets the slab iff ``s`` lies in
    ``[-ey / t_a, (y_top - ey) / t_b]``, where ``t_a`` (``t_b``) is ``t`` when the
    eye is above the floor (below the top) and ``t_far`` otherwise.  The rows come
    from the slopes by Eq. 4.5, as an element's do, so no row an element could
    still draw is left out.
    """
    t_a = jnp.where(ey >= 0, t, consts.t_far)
    t_b = jnp.where(ey <= y_top, t, consts.t_far)
    s_lo = (0.0 - ey) / t_a
    s_hi = (y_top - ey) / t_b
    # A hair wider for rounding (an element's slopes are computed from the
    # voxel heights, not from these bounds); a whole row wider would keep rows
    # no element can reach open to the map's edge.
    tol = 1e-5 * (jnp.abs(s_lo) + jnp.abs(s_hi)) + 1e-7
    s_lo = jnp.maximum(s_lo - tol, consts.s_min)
    s_hi = jnp.minimum(s_hi + tol, consts.s_max)
    a0, a1 = _rows_of(consts, s_lo, s_hi, fy)
    return a0, jnp.where(s_lo <= s_hi, a1, a0)


class _PlaneConsts(NamedTuple):
    """Per-plane constants of the traversal (:func:`_plane_init`), all () float32."""

    hx: jax.Array  # x of the plane's unit x-z direction
    hz: jax.Array  # z of the plane's unit x-z direction
    inv_x: jax.Array  # 1 / hx (guarded)
    inv_z: jax.Array  # 1 / hz (guarded)
    t_far: jax.Array  # horizontal distance where the walk ends (map exit or far plane)
    s_min: jax.Array  # smallest slope dy/dt visible in the plane
    s_max: jax.Array  # largest slope dy/dt visible in the plane
    hf: jax.Array  # camera forward along the plane direction (Eq. 4.5 denominator)
    p_num: jax.Array  # Eq. 4.5 numerator, constant term
    q_num: jax.Array  # Eq. 4.5 numerator, slope term


class _PlaneState(NamedTuple):
    """One plane at the start of its walk (:func:`_plane_init`; vmap adds a plane axis)."""

    ix: jax.Array  # () int32, map cell x at level ``lev``
    iz: jax.Array  # () int32, map cell z at level ``lev``
    lev: jax.Array  # () int32, mip level of the cell
    t: jax.Array  # () float32, horizontal distance where the walk entered the cell
    done: jax.Array  # () bool, plane finished (left the map, far limit, horizon closed)
    lo: jax.Array  # () int32, floating horizon: first row not yet drawn
    hi: jax.Array  # () int32, floating horizon: one past the last row not yet drawn
    cov: jax.Array  # (ceil(rows / 32),) uint32, 1-bit coverage map of the column
    first: jax.Array  # (ceil(rows / 32),) int32, list entry that first drew in each word
    nbuf: jax.Array  # () int32, elements drawn so far (may exceed K: overflow)
    stats: jax.Array  # (3,) int32, elements in visited columns / processed / drawn


def _cell_exit(consts: _PlaneConsts, cam: Camera, ix, iz, lev):
    """Exact 2-D DDA (Amanatides & Woo): ``(cell size, exit t, exit through x?)`` of a cell."""
    hx, hz, big = consts.hx, consts.hz, jnp.float32(1e30)
    c = jnp.left_shift(1, lev).astype(jnp.float32)
    bx = (hx > 0).astype(jnp.int32)
    bz = (hz > 0).astype(jnp.int32)
    nx = ((ix + bx).astype(jnp.float32) * c - cam.position[0]) * consts.inv_x
    nz = ((iz + bz).astype(jnp.float32) * c - cam.position[2]) * consts.inv_z
    nx = jnp.where(jnp.abs(hx) < 1e-12, big, nx)
    nz = jnp.where(jnp.abs(hz) < 1e-12, big, nz)
    return c, jnp.minimum(jnp.minimum(nx, nz), consts.t_far), nx <= nz


# ---------------------------------------------------------------------------
# A plane's start and a column's order
# ---------------------------------------------------------------------------


def _unrank(rank, n, m):
    """The index of a column's ``rank``-th element front to back.

    A column's ``n`` elements are indexed from the top; the first ``m`` lie above
    the eye.  Rays that hit elements below the eye descend, so those come first,
    top down (index ``m`` on); rays that hit elements above it ascend, so those
    come next, bottom up (index ``m - 1`` down).  The two groups never compete
    for one ray, so one order serves both.
    """
    return jnp.where(rank < n - m, m + rank, m - 1 - (rank - (n - m)))


def _plane_init(rle, cam: Camera, seg: Segments, plane, *, rows: int, n_words: int):
    """Per-plane constants and the initial loop state (coverage of ``n_words`` words)."""
    # s_min / s_max: slopes visible in this plane, to clip element slopes to the screen.
    h, lo, hi, s_min, s_max = plane_extent(cam, seg, plane, rows=rows)
    s_idx = jnp.clip(jnp.searchsorted(seg.start + seg.count, plane, side="right"), 0, 3)
    vertical = s_idx < 2
    right, up, forward = camera_basis(cam)
    fx, fy = focal_lengths(cam)
    eye = cam.position
    ex, ez = eye[0], eye[2]
    hx, hz = h[0], h[1]
    inv_x = _safe_div(1.0, hx, 1e-12)
    inv_z = _safe_div(1.0, hz, 1e-12)
    # Eq. 4.5 in the plane: the ray-buffer coordinate of slope s is the
    # projective map (p + q s) / (g + d s) of the plane's camera-space terms.
    hr = right[0] * hx + right[2] * hz
    hu = up[0] * hx + up[2] * hz
    hf = forward[0] * hx + forward[2] * hz
    cx, cy = cam.principal[0], cam.principal[1]
    p_num = jnp.where(vertical, cy * hf - fy * hu, cx * hf + fx * hr)
    q_num = jnp.where(vertical, cy * forward[1] - fy * up[1], cx * forward[1] + fx * right[1])
    # Entry into the map's x-z box (2-D slab test).
    X0, Z0 = float(rle.shape[0]), float(rle.shape[2])
    tx0, tx1 = (0.0 - ex) * inv_x, (X0 - ex) * inv_x
    tz0, tz1 = (0.0 - ez) * inv_z, (Z0 - ez) * inv_z
    t_enter = jnp.maximum(jnp.maximum(jnp.minimum(tx0, tx1), jnp.minimum(tz0, tz1)), 0.0)
    t_exit = jnp.minimum(jnp.maximum(tx0, tx1), jnp.maximum(tz0, tz1))
    t_far = jnp.minimum(t_exit, cam.far)
    p0x, p0z = ex + hx * t_enter, ez + hz * t_enter
    ix0 = jnp.clip(jnp.floor(p0x), 0, X0 - 1).astype(jnp.int32)
    iz0 = jnp.clip(jnp.floor(p0z), 0, Z0 - 1).astype(jnp.int32)
    done0 = (t_enter >= t_far) | (lo >= hi)
    carry0 = _PlaneState(
        ix=ix0,
        iz=iz0,
        lev=jnp.int32(0),
        t=t_enter,
        done=done0,
        lo=lo,
        hi=hi,
        cov=jnp.zeros((n_words,), jnp.uint32),
        first=jnp.full((n_words,), NO_ENTRY, jnp.int32),
        nbuf=jnp.int32(0),
        stats=jnp.zeros(3, jnp.int32),
    )
    consts = _PlaneConsts(hx, hz, inv_x, inv_z, t_far, s_min, s_max, hf, p_num, q_num)
    return consts, carry0
