"""Vanishing point, concentric planes and their parameters (thesis 4.5.1 - 4.5.3).

The scene is cut by vertical half-planes that all contain the vertical line through
the eye.  Each half-plane projects to a straight screen line starting at the
vanishing point ``vp`` (Eq. 4.2, 4.3).  The screen is split into four 90-degree
segments around ``vp`` with ``np_i = 2 dist(vp, border_i)`` planes each (Eq. 4.4).
:func:`plane_parameters` gives one plane's per-row rays, :func:`plane_extent` the
same rows in closed form (the traversal's set-up).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxgfx._src.camera import Camera, camera_basis, focal_lengths, screen_to_camera
from jaxgfx._src.voxel.grid import _safe_div

__all__ = [
    "Segments",
    "scene_rect",
    "PlaneParams",
    "vanishing_point",
    "screen_segments",
    "plane_parameters",
    "plane_extent",
]


class Segments(NamedTuple):
    """The four screen segments around the vanishing point (Eq. 4.4, Fig. 4.12).

    Segment order: 0 top, 1 bottom (planes textured along screen y), 2 left,
    3 right (along screen x).  A plane is named by ``u``, where its screen line
    crosses the segment's reference line ``a = a_ref`` (a = y for 0/1, x for 2/3).

    Attributes:
        vp_h: (3,) homogeneous vanishing point ``(x w, y w, w)``; w = 0 for a
            level camera (vp at infinity).
        u_lo: (4,) smallest plane parameter per segment.
        u_hi: (4,) largest plane parameter per segment.
        count: (4,) int32 planes per segment (0 for an empty segment).
        start: (4,) int32 first plane index of each segment in the ray buffer.
        phase: () float32, plane ``i`` sits at ``u_lo + (i + phase) du``; chosen
            so that with an integer ``oversample`` every pixel centre of the
            far border row has its own plane (0.5 for odd, 0 for even).
    """

    vp_h: jax.Array
    u_lo: jax.Array
    u_hi: jax.Array
    # The field name shadows tuple.count (mypy); it is public API and stays.
    count: jax.Array  # type: ignore[assignment]
    start: jax.Array
    phase: jax.Array


class PlaneParams(NamedTuple):
    """Parameters of one concentric plane (4.5.3).

    Attributes:
        direction: (2,) unit x-z direction of the half-plane (its rotation about y).
        row_slope: (R,) dy / dt of the ray of each ray-buffer row in the plane
            (t = horizontal distance from the eye).
        row_scale: (R,) horizontal length per unit depth of each row's ray.
        valid: (R,) bool rows that belong to this plane on screen.
        lo: () int32 first valid row (initial floating horizon).
        hi: () int32 one past the last valid row.
    """

    direction: jax.Array
    row_slope: jax.Array
    row_scale: jax.Array
    valid: jax.Array
    lo: jax.Array
    hi: jax.Array


# ---------------------------------------------------------------------------
# 4.5.1 Vanishing point
# ---------------------------------------------------------------------------


def vanishing_point(cam: Camera) -> jax.Array:
    """Screen image of the vertical through the eye, homogeneous (Eq. 4.2, 4.3).

    ``vp = (0, 1, 0) * (-d / sin(pitch))`` projected by the camera matrix.  In
    homogeneous screen coordinates this stays finite for a level camera
    (pitch 0, vp at infinity, w = 0) and for straight up/down (vp at the centre).

    Returns:
        (3,) ``(x w, y w, w)`` with ``w = sin(pitch)`` for a camera without roll.
    """
    right, up, forward = camera_basis(cam)
    fx, fy = focal_lengths(cam)
    cx, cy = cam.principal[0], cam.principal[1]
    w = forward[1]
    return jnp.stack([cx * w + fx * right[1], cy * w - fy * up[1], w])


# ---------------------------------------------------------------------------
# 4.5.2 Concentric planes: four screen segments (Eq. 4.4)
# ---------------------------------------------------------------------------


def _seg_axes(cam: Camera, s: int):
    """(size_a, size_b, a_ref, vertical?, negative side?) of segment s (static)."""
    W, H = cam.width, cam.height
    if s in (0, 1):
        size_a, size_b = H, W
    else:
        size_a, size_b = W, H
    neg = s in (0, 2)
    a_ref = -float(size_a) if neg else 2.0 * size_a
    return float(size_a), float(size_b), a_ref, s in (0, 1), neg


def _ab(vp_h, vertical):
    return (vp_h[1], vp_h[0]) if vertical else (vp_h[0], vp_h[1])


def _sgn_w(w):
    return jnp.where(w < 0, -1.0, 1.0)


def scene_rect(cam: Camera, shape) -> tuple[jax.Array, jax.Array]:
    """Screen rectangle holding the scene box ``[0, shape)`` and its farthest depth.

    Returns:
        ``(rect (4,) = (x0, x1, y0, y1) clipped to the screen, z_max ())``; the
        whole screen and ``z_max = inf`` when a corner of the box is not in front of
        the eye (the box's image is then unbounded).
    """
    corners = jnp.asarray(
        [[x, y, z] for x in (0, shape[0]) for y in (0, shape[1]) for z in (0, shape[2])],
        jnp.float32,
    )
    right, up, forward = camera_basis(cam)
    rel = corners - cam.position
    zc = rel @ forward
    fx, fy = focal_lengths(cam)
    front = jnp.all(zc > 1e-3)
    zs = jnp.where(front, zc, 1.0)
    xs = cam.principal[0] + fx * (rel @ right) / zs
    ys = cam.principal[1] - fy * (rel @ up) / zs
    W, H = float(cam.width), float(cam.height)
    # Whole pixels (planes stay on pixel centres, see Segments.phase) and one
    # of margin: a plane on the box's image edge still sees its border voxels.
    rect = jnp.stack(
        [
            jnp.clip(jnp.floor(jnp.min(xs)) - 1.0, 0.0, W),
            jnp.clip(jnp.ceil(jnp.max(xs)) + 1.0, 0.0, W),
            jnp.clip(jnp.floor(jnp.min(ys)) - 1.0, 0.0, H),
            jnp.clip(jnp.ceil(jnp.max(ys)) + 1.0, 0.0, H),
        ]
    )
    full = jnp.asarray([0.0, W, 0.0, H], jnp.float32)
    return jnp.where(front, rect, full), jnp.where(front, jnp.max(zc), jnp.inf)


def screen_segments(
    cam: Camera,
    vp_h: jax.Array,
    *,
    num_planes: int,
    oversample: float = 1.0,
    scene_shape=None,
    planes_per_voxel: float = 0.0,
    lod_distance=jnp.inf,
    levels: int = 1,
):
    """Splits the screen into four segments and counts their planes (Eq. 4.4).

    ``np_i`` is the number of planes that gives a spacing of ``1 / oversample``
    pixels on the segment's farthest screen row (= ``2 dist(vp, border_i)`` when
    vp is on screen).  If the total exceeds the static ``num_planes`` budget all
    counts are scaled down.

    With ``scene_shape`` (not in the thesis) the planes cover only the screen
    rectangle of the scene box's projection, and with
    ``planes_per_voxel = k > 0`` they are spaced at most ``1 / k`` voxels apart
    at the box's farthest depth, so that a column narrower than a pixel is still
    crossed by a plane: the density follows the distance, up to the budget
    (above ``oversample`` per pixel, which the budget always holds).  With a
    finite ``lod_distance`` (mip level ``l`` from ``lod_distance 2^(l-1)``, as in
    :func:`~jaxgfx.raycast.render_rle`, ``levels`` of them) a cell at horizontal
    distance ``t`` is wider than ``t / lod_distance`` voxels, so depth / cell size
    never exceeds ``sqrt(lod_distance^2 + dy^2)`` (``dy``: the box's largest
    height above or below the eye) nor falls below ``z_max / 2^(levels-1)``: the
    spacing is set by that instead of ``z_max`` (a 2,560-voxel instance map seen
    from its corner took 18,191 planes at 3 per level-0 voxel).

    Returns:
        :class:`Segments`.
    """
    w = vp_h[2]
    sw = _sgn_w(w)
    u_lo: list[jax.Array] = []
    u_hi: list[jax.Array] = []
    need_s: list[jax.Array] = []
    more_s: list[jax.Array] = []
    if scene_shape is None:
        rect = jnp.asarray([0.0, cam.width, 0.0, cam.height], jnp.float32)
        z_max = jnp.float32(jnp.inf)
    else:
        rect, z_max = scene_rect(cam, scene_shape)
    fx, fy = focal_lengths(cam)
    z_eff = z_max
    if scene_shape is not None:
        ey = cam.position[1]
        dy = jnp.maximum(jnp.abs(ey), jnp.abs(scene_shape[1] - ey))
        lod = jnp.asarray(lod_distance, jnp.float32)
        per_cell = jnp.maximum(jnp.sqrt(lod * lod + dy * dy), z_max / 2.0 ** (levels - 1))
        z_eff = jnp.minimum(z_max, per_cell)
    for s in range(4):
        size_a, size_b, a_ref, vertical, neg = _seg_axes(cam, s)
        va, vb = _ab(vp_h, vertical)
        vp_a = jnp.clip(_safe_div(va, w), -1e7, 1e7)
        vp_b = jnp.clip(_safe_div(vb, w), -1e7, 1e7)
        amin, amax = (rect[2], rect[3]) if vertical else (rect[0], rect[1])
        bmin, bmax = (rect[0], rect[1]) if vertical else (rect[2], rect[3])
        a0 = amin if neg else jnp.clip(vp_a, amin, amax)
        a1 = jnp.clip(vp_a, amin, amax) if neg else amax
        # Wedge of +-45 degrees around the segment's direction from vp.
        half = jnp.abs(a_ref - vp_a)
        side = 1.0 if neg else -1.0
        us_s = []
        for a in (a0, a1):
            for b in (bmin, bmax):
                da = va - a * w
                db = vb - b * w
                # A corner on vp's own line (``a`` is vp_a, clipped: vp inside the
                # segment's range) looks along the border: its side is the segment's,
                # not the sign of ``va - a w``'s rounding residue, which changes
                # with the compiler's contractions and would swing u across the wedge.
                flat = (a == vp_a) | (jnp.abs(da) < 1e-9)
                da = jnp.where(flat, 1e-9 * sw * side, da)
                u = b + (a_ref - a) * db / da
                us_s.append(jnp.clip(u, vp_b - half, vp_b + half))
        us = jnp.stack(us_s)
        lo_u, hi_u = jnp.min(us), jnp.max(us)
        a_far = amin if neg else amax
        ratio = jnp.abs(a_far * w - va) / jnp.maximum(jnp.abs(a_ref * w - va), 1e-9)
        live = (a1 > a0) & (hi_u > lo_u)
        n = jnp.ceil((hi_u - lo_u) * ratio * oversample)
        n = jnp.where(live, jnp.maximum(n, 1.0), 0.0)
        # Planes per pixel for a spacing of 1 / k voxels at depth z_max (one
        # voxel there is f / z_max pixels across the plane direction).
        f_b = fx if vertical else fy
        # (None while the box is not wholly in front: the thesis spacing.)
        dense = jnp.where(jnp.isfinite(z_max), planes_per_voxel * z_eff / f_b, 0.0)
        more = jnp.ceil((hi_u - lo_u) * ratio * jnp.maximum(dense, oversample))
        more = jnp.where(live, jnp.maximum(more, n), 0.0)
        u_lo.append(lo_u)
        u_hi.append(hi_u)
        need_s.append(n)
        more_s.append(more)
    need = jnp.stack(need_s)
    more = jnp.stack(more_s)
    total = jnp.sum(need)
    scale = jnp.minimum(1.0, num_planes / jnp.maximum(total, 1.0))
    count = jnp.where(need > 0, jnp.maximum(jnp.floor(need * scale), 1.0), 0.0)
    # The distance-driven planes take what the budget has left.
    spare = jnp.maximum(num_planes - jnp.sum(count), 0.0)
    extra = more - need
    fill = jnp.minimum(1.0, spare / jnp.maximum(jnp.sum(extra), 1.0))
    count = jnp.where(scale >= 1.0, count + jnp.floor(extra * fill), count)
    count = jnp.minimum(count, num_planes).astype(jnp.int32)
    start = jnp.cumsum(count) - count
    phase = jnp.float32((0.5 * oversample) % 1.0)
    return Segments(vp_h, jnp.stack(u_lo), jnp.stack(u_hi), count, start.astype(jnp.int32), phase)


# ---------------------------------------------------------------------------
# 4.5.3 Plane parameters
# ---------------------------------------------------------------------------


def _screen_dir(cam: Camera, x, y):
    """World direction (3,) of screen point (x, y), scaled to camera z = 1."""
    right, up, forward = camera_basis(cam)
    cx, cy = screen_to_camera(cam, x, y)
    return cx * right + cy * up + forward


def _plane_u(seg: Segments, plane):
    """(segment, alive, u) of a plane: its parameter on the segment's reference line."""
    s = jnp.clip(jnp.searchsorted(seg.start + seg.count, plane, side="right"), 0, 3)
    i = plane - seg.start[s]
    alive = (i < seg.count[s]) & (i >= 0)
    n = jnp.maximum(seg.count[s], 1)
    u = seg.u_lo[s] + (i.astype(jnp.float32) + seg.phase) * (seg.u_hi[s] - seg.u_lo[s]) / n
    return s, alive, u


def _unit_xz(d):
    """The x-z part of a direction, normalised (+z for a vertical one; double where)."""
    h = jnp.stack([d[0], d[2]])
    hn = jnp.linalg.norm(h)
    return jnp.where(hn > 1e-12, h / jnp.where(hn > 1e-12, hn, 1.0), jnp.array([0.0, 1.0]))


def plane_parameters(cam: Camera, seg: Segments, plane: jax.Array, *, rows: int) -> PlaneParams:
    """Parameters of ONE plane of the ray buffer (4.5.3); vmap over ``plane``.

    Args:
        cam: camera.
        seg: :class:`Segments` of this frame.
        plane: () int32 plane index in ``[0, num_planes)``.
        rows: static ray-buffer column length, ``max(width, height)``.
    """
    s, alive, u = _plane_u(seg, plane)
    vp_h = seg.vp_h
    w = vp_h[2]
    sw = _sgn_w(w)
    r = jnp.arange(rows, dtype=jnp.float32) + 0.5
    outs = []
    for k in range(4):
        size_a, size_b, a_ref, vertical, neg = _seg_axes(cam, k)
        va, vb = _ab(vp_h, vertical)
        da = va - a_ref * w
        db = vb - u * w
        b_r = u + (r - a_ref) * _safe_div(db, da)
        # Side of vp: negative-side segments hold rows with a < vp_a.
        side_ok = ((r * w - va) * sw < 0) if neg else ((r * w - va) * sw > 0)
        valid = side_ok & (r < size_a) & (b_r > -1.0) & (b_r < size_b + 1.0)
        qx, qy = (u, a_ref) if vertical else (a_ref, u)
        xs, ys = (b_r, r) if vertical else (r, b_r)
        outs.append((qx, qy, xs, ys, valid))
    pick = lambda j: jnp.stack([o[j] for o in outs])[s]  # noqa: E731
    qx, qy, xs, ys, valid = pick(0), pick(1), pick(2), pick(3), pick(4)
    dq = _screen_dir(cam, qx, qy)
    h = _unit_xz(dq)
    d = jax.vmap(lambda x, y: _screen_dir(cam, x, y))(xs, ys)
    scale = d[:, 0] * h[0] + d[:, 2] * h[1]
    valid = valid & alive & (scale > 1e-9)
    safe_scale = jnp.where(valid, scale, 1.0)
    slope = jnp.where(valid, d[:, 1] / safe_scale, 0.0)
    idx = jnp.arange(rows)
    lo = jnp.min(jnp.where(valid, idx, rows)).astype(jnp.int32)
    hi = (jnp.max(jnp.where(valid, idx, -1)) + 1).astype(jnp.int32)
    hi = jnp.maximum(hi, lo)
    return PlaneParams(h, slope, safe_scale, valid, lo, hi)


def _half_line(alpha, beta, lo, hi):
    """Narrows the row range ``[lo, hi)`` to rows ``i`` with ``alpha (i + 0.5) + beta > 0``."""
    flat = jnp.abs(alpha) < 1e-12
    root = jnp.clip(-beta / jnp.where(flat, 1.0, alpha) - 0.5, -1e9, 1e9)
    lo = jnp.where(~flat & (alpha > 0), jnp.maximum(lo, jnp.floor(root).astype(jnp.int32) + 1), lo)
    hi = jnp.where(~flat & (alpha < 0), jnp.minimum(hi, jnp.ceil(root).astype(jnp.int32)), hi)
    return lo, jnp.where(flat & (beta <= 0), lo, hi)


def plane_extent(cam: Camera, seg: Segments, plane: jax.Array, *, rows: int):
    """Row range and slope range of ONE plane in closed form (4.5.3); vmap over ``plane``.

    The same rows as :func:`plane_parameters` marks valid, without building
    the per-row arrays: every condition on a row (its side of vp, on screen,
    looking forward along the plane) is linear in the row coordinate, so the
    valid rows are one interval, and the in-plane slope ``dy/dt`` is a ratio
    of linear functions of it, monotonic there, so its range is set by the
    two end rows.  This is the traversal's per-plane set-up; per-row arrays
    for all planes cost more than the traversal of a small scene.

    Returns:
        ``(direction (2,), lo (), hi (), s_min (), s_max ())``; ``lo >= hi``
        for a plane without rows.
    """
    s, alive, u = _plane_u(seg, plane)
    vp_h = seg.vp_h
    w = vp_h[2]
    sw = _sgn_w(w)
    right, up, forward = camera_basis(cam)
    fx, fy = focal_lengths(cam)
    pa = fy / fx
    cx, cy = cam.principal[0], cam.principal[1]
    per = []
    for k in range(4):
        size_a, size_b, a_ref, vertical, neg = _seg_axes(cam, k)
        va, vb = _ab(vp_h, vertical)
        q = _safe_div(vb - u * w, va - a_ref * w)  # b(r) = q r + c0
        c0 = u - a_ref * q
        qx, qy = (u, a_ref) if vertical else (a_ref, u)
        # Screen point (x, y) = (bx r + cx0, by r + cy0) along the plane's line.
        bx, cx0, by, cy0 = (q, c0, 1.0, 0.0) if vertical else (1.0, 0.0, q, c0)
        side_k = -1.0 if neg else 1.0
        per.append((qx, qy, bx, cx0, by, cy0, q, c0, size_a, size_b, side_k, va))
    pick = lambda j: jnp.stack([jnp.asarray(p[j], jnp.float32) for p in per])[s]  # noqa: E731
    qx, qy, bx, cx0, by, cy0, q, c0, size_a, size_b, side, va = (pick(j) for j in range(12))
    dq = _screen_dir(cam, qx, qy)
    h = _unit_xz(dq)

    def ray(v):
        # Component of a screen direction along the plane (h) and along y,
        # as linear functions (slope, offset) of the row coordinate.
        rv = (right[0] * h[0] + right[2] * h[1]) if v is None else right[1]
        uv = (up[0] * h[0] + up[2] * h[1]) if v is None else up[1]
        fv = (forward[0] * h[0] + forward[2] * h[1]) if v is None else forward[1]
        rv = rv * pa  # / fx = * (fy / fx) / fy
        return (bx * rv - by * uv) / fy, ((cx0 - cx) * rv + (cy - cy0) * uv) / fy + fv

    lo = jnp.int32(0)
    hi = jnp.minimum(jnp.int32(rows), jnp.ceil(size_a - 0.5).astype(jnp.int32))
    lo, hi = _half_line(side * w * sw, -side * va * sw, lo, hi)  # vp's side
    lo, hi = _half_line(q, c0 + 1.0, lo, hi)  # b > -1
    lo, hi = _half_line(-q, size_b + 1.0 - c0, lo, hi)  # b < size_b + 1
    a_s, b_s = ray(None)
    lo, hi = _half_line(a_s, b_s - 1e-9, lo, hi)  # looks forward along the plane
    hi = jnp.where(alive, jnp.maximum(hi, lo), lo)
    a_y, b_y = ray(1)
    slope = lambda r: (a_y * r + b_y) / jnp.maximum(a_s * r + b_s, 1e-9)  # noqa: E731
    s0 = slope(lo.astype(jnp.float32) + 0.5)
    s1 = slope(hi.astype(jnp.float32) - 0.5)
    return h, lo, hi, jnp.minimum(s0, s1), jnp.maximum(s0, s1)
