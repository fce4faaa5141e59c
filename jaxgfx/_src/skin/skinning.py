"""Spline skinning with deformation styles, frames per vertex (thesis 5.5 and 5.7, Eq. 5.7, 5.13).

The exact path: every influence of a vertex evaluates its spline's frame at the vertex's own
``x``, applies the style in spline space and maps ``v'`` to the world; the results are blended by
the skinning weights.  The thesis's fast path with sampled frames is
:mod:`jaxgfx._src.skin.sampled`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxgfx._src.skin.binding import SkinBinding, require_binding
from jaxgfx._src.skin.geometry import _normalize
from jaxgfx._src.skin.rig import SplinePose, SplineRig, validate_pose
from jaxgfx._src.skin.spline import spline_frame, start_normal
from jaxgfx._src.skin.styles import Style, _check_style, _pose_weights, _style_flags, apply_style

__all__ = ["skin_vertex_exact", "skin_exact"]


def _dominant_mask(weight: jax.Array, dominant_only: bool) -> jax.Array:
    if not dominant_only:
        return jnp.ones_like(weight, dtype=bool)
    return jnp.arange(weight.shape[0]) == jnp.argmax(weight)


def skin_vertex_exact(
    pose: SplinePose,
    normal0: jax.Array,
    spline: jax.Array,
    weight: jax.Array,
    x: jax.Array,
    local: jax.Array,
    local_normal: jax.Array,
    style: Style | None = None,
    *,
    styles: str = "none",
    dominant_only: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """Spline skinning of one vertex with frames evaluated at its own ``x`` (Eq. 5.7 / 5.13).

    Args:
        pose: the pose.
        normal0: (K, 3) posed start normals (``vmap(start_normal)``).
        spline, weight, x: (I,) binding of the vertex.
        local, local_normal: (I, 3) ``v'`` and the spline-space normal.
        style: a :class:`Style` (needed unless ``styles == 'none'``).
        styles: 'none', 'radial', 'rect' or 'both'.
        dominant_only: style only the influence with the largest weight (thesis 5.8.2).

    Returns:
        Position (3,) and unit normal (3,).
    """
    radial, rect = _style_flags(styles)
    styled = _dominant_mask(weight, dominant_only)

    def one(k, xi, v, n, use_style):
        pts, a, tw = pose.points[k], pose.stiffness[k], pose.twist[k]
        frame = spline_frame(pts, a, tw, normal0[k], xi)
        if radial or rect:
            bend, twist = _pose_weights(pts, tw)
            sv, sn = apply_style(style, v, n, xi, bend, twist, radial=radial, rect=rect)
            v = jnp.where(use_style, sv, v)
            n = jnp.where(use_style, sn, n)
        return frame[:, :3] @ v + frame[:, 3], frame[:, :3] @ n

    pos, nrm = jax.vmap(one)(spline, x, local, local_normal, styled)
    normal = jnp.dot(weight, nrm)
    return jnp.dot(weight, pos), _normalize(normal, jnp.array([0.0, 1.0, 0.0]))


def skin_exact(
    rig: SplineRig,
    pose: SplinePose,
    binding: SkinBinding,
    style: Style | None = None,
    *,
    styles: str = "none",
    dominant_only: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """Exact spline skinning of a whole mesh: vmap of :func:`skin_vertex_exact`; (V,3), (V,3).

    Raises:
        ValueError: a malformed pose or style, and inside :func:`~jaxgfx.checks.checked` also
            non-finite traced pose, style or binding values and spline indices out of range.
    """
    _style_flags(styles)
    if styles != "none" and style is None:
        raise ValueError("style is required when styles != 'none'")
    where = "skin_exact"
    validate_pose(rig, pose, where=where)
    require_binding(binding, rig.num_splines, where)
    pose = jax.tree_util.tree_map(jnp.asarray, pose)
    style = None if style is None else jax.tree_util.tree_map(jnp.asarray, style)
    if style is not None:
        _check_style(style, where)
    n0 = jax.vmap(start_normal)(rig.bind.points, rig.reference_normal, pose.points)
    fn = lambda s, w, x, v, n: skin_vertex_exact(  # noqa: E731
        pose, n0, s, w, x, v, n, style, styles=styles, dominant_only=dominant_only
    )
    return jax.vmap(fn)(
        binding.spline, binding.weight, binding.x, binding.local, binding.local_normal
    )
