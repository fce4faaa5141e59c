"""Deformation styles: scale envelopes in spline space (thesis 5.6, Eq. 5.8-5.12).

A :class:`Style` is independent of any mesh or spline: three scale textures and three scale
curves, looked up at a vertex's spline parameter ``x`` and cross-section angle ``α``, weighted by
the pose (bend ``β`` and twist ``γ``) and applied to ``v'`` in spline space before the spline
frame maps it to the world (Eq. 5.13, :mod:`jaxgfx._src.skin.skinning`).

Conventions and the choices the thesis leaves open:

* **Pose weights of the styles.** ``β = ∠(Δ12, Δ23) ∈ [0, π]`` enters the weights as ``β/π`` and
  the twist as ``|γ|/π``, so ``w_f, w_l ∈ [0, 1]`` always and ``w_r ∈ [0, 1]`` for twists up to 180°
  (larger sums are normalized by Eq. 5.9's ``max(1, w_sum)``).
* **Radial scaling** scales only the cross-section coordinates ``(v'_x, v'_y)`` of ``v'``; the
  binding puts bound vertices on the plane ``v'_z = 0`` (Eq. 5.5), so this equals Eq. 5.8 there and
  keeps vertices beyond the spline ends from being stretched along the tangent.
* **Texture layout.** Texture row 0 is ``α = 0`` (the ``b_B`` side), the last row ``α = π``.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxgfx._src.checks import require_finite
from jaxgfx._src.skin.geometry import _EPS_SQ
from jaxgfx._src.skin.spline import bend_angle

__all__ = [
    "Style",
    "make_style",
    "identity_style",
    "muscle_style",
    "sample_texture",
    "sample_curve",
    "radial_scale",
    "rect_scale",
    "apply_style",
]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Style:
    """A deformation style (thesis 5.6), independent of any mesh or spline.

    Attributes:
        textures: (3, A, X) scale textures ``T_f, T_l, T_r`` (frontal, lateral, radial), >= 0;
            rows sample ``α/π`` from 0 to 1, columns sample ``x`` from 0 to 1 (nodes at the ends).
        curves: (3, X) scale curves ``C_f, C_l, C_r`` sampled at ``x`` from 0 to 1, >= 0.
        hollow: () displacement of the scaling origin along ``b_B`` (Fig. 5.23), in mesh units.
    """

    textures: jax.Array
    curves: jax.Array
    hollow: jax.Array


# ----------------------------------------------------------------------------------------------
# construction and validation
# ----------------------------------------------------------------------------------------------


def make_style(textures, curves, hollow=0.0) -> Style:
    """Build a :class:`Style`, checking ranks, sizes, finiteness and non-negativity (Eq. 5.9, 5.12).

    Args:
        textures: (3, A, X) scale textures, A, X >= 2.
        curves: (3, X') scale curves, X' >= 2.
        hollow: displacement of the scaling origin along ``b_B``.
    """
    t = np.asarray(textures, np.float32)
    c = np.asarray(curves, np.float32)
    if t.ndim != 3 or t.shape[0] != 3 or t.shape[1] < 2 or t.shape[2] < 2:
        raise ValueError(f"textures must have shape (3, A, X) with A, X >= 2, got {t.shape}")
    if c.ndim != 2 or c.shape[0] != 3 or c.shape[1] < 2:
        raise ValueError(f"curves must have shape (3, X) with X >= 2, got {c.shape}")
    if not np.all(np.isfinite(t)) or np.any(t < 0):
        raise ValueError("textures must be finite and >= 0 (Eq. 5.9)")
    if not np.all(np.isfinite(c)) or np.any(c < 0):
        raise ValueError("curves must be finite and >= 0 (Eq. 5.12)")
    if not np.isfinite(float(hollow)):
        raise ValueError("hollow must be finite")
    return Style(textures=jnp.asarray(t), curves=jnp.asarray(c), hollow=jnp.float32(hollow))


def _check_style(style: Style, where: str | None = None) -> None:
    """Shape checks that work on traced styles too (values are checked by make_style, and
    traced ones inside :func:`~jaxgfx.checks.checked`: a NaN texel spreads over its vertices)."""
    t, c = jnp.shape(style.textures), jnp.shape(style.curves)
    if len(t) != 3 or t[0] != 3 or t[1] < 2 or t[2] < 2:
        raise ValueError(f"style.textures must have shape (3, A, X) with A, X >= 2, got {t}")
    if len(c) != 2 or c[0] != 3 or c[1] < 2:
        raise ValueError(f"style.curves must have shape (3, X) with X >= 2, got {c}")
    require_finite("style.textures", style.textures, where)
    require_finite("style.curves", style.curves, where)


def identity_style(texture_shape: tuple[int, int] = (64, 32), curve_size: int = 32) -> Style:
    """The style whose textures and curves are all one: no change (Eq. 5.10)."""
    return make_style(np.ones((3, *texture_shape)), np.ones((3, curve_size)))


def muscle_style(strength: float = 0.35, size: tuple[int, int] = (16, 16)) -> Style:
    """A muscle bulge (Fig. 5.17/5.21): the frontal texture swells around ``x = 0.3`` on the
    ``α ≈ π`` side; lateral texture, radial texture and curves are identity."""
    rows, cols = size
    alpha = np.linspace(0.0, 1.0, rows)[:, None]
    x = np.linspace(0.0, 1.0, cols)[None, :]
    bump = np.exp(-(((x - 0.3) / 0.15) ** 2)) * np.clip((alpha - 0.4) / 0.6, 0.0, 1.0)
    textures = np.stack([1.0 + strength * bump, np.ones((rows, cols)), np.ones((rows, cols))])
    return make_style(textures, np.ones((3, cols)))


# ----------------------------------------------------------------------------------------------
# texture and curve lookups
# ----------------------------------------------------------------------------------------------


def sample_texture(texture: jax.Array, x: jax.Array, v: jax.Array) -> jax.Array:
    """Bilinear sample of ``texture`` (C, A, X) at ``x`` (columns) and ``v = α/π`` (rows); (C,)."""
    n_rows, n_cols = texture.shape[-2], texture.shape[-1]
    fc = jnp.clip(x, 0.0, 1.0) * (n_cols - 1)
    fr = jnp.clip(v, 0.0, 1.0) * (n_rows - 1)
    c0 = jnp.clip(jnp.floor(fc).astype(jnp.int32), 0, n_cols - 2)
    r0 = jnp.clip(jnp.floor(fr).astype(jnp.int32), 0, n_rows - 2)
    tc = fc - c0
    tr = fr - r0
    top = texture[..., r0, c0] * (1 - tc) + texture[..., r0, c0 + 1] * tc
    bottom = texture[..., r0 + 1, c0] * (1 - tc) + texture[..., r0 + 1, c0 + 1] * tc
    return top * (1 - tr) + bottom * tr


def sample_curve(curves: jax.Array, x: jax.Array) -> jax.Array:
    """Piecewise-linear sample of ``curves`` (C, X) at ``x`` in [0, 1]; returns (C,)."""
    n = curves.shape[-1]
    f = jnp.clip(x, 0.0, 1.0) * (n - 1)
    i0 = jnp.clip(jnp.floor(f).astype(jnp.int32), 0, n - 2)
    t = f - i0
    return curves[..., i0] * (1 - t) + curves[..., i0 + 1] * t


def _blend(samples: jax.Array, weights: jax.Array) -> jax.Array:
    """``Σ w_i s_i / max(1, Σ w_i) + max(1 - Σ w_i, 0)`` (Eq. 5.9 / 5.12)."""
    w_sum = jnp.sum(weights)
    return jnp.dot(weights, samples) / jnp.maximum(1.0, w_sum) + jnp.maximum(1.0 - w_sum, 0.0)


def _cross_section(local: jax.Array, hollow: jax.Array):
    """Radius-free angle terms of ``v'`` about the (displaced) origin: cos α, |sin α|, α/π."""
    vx = local[0]
    vy = local[1] - hollow
    r_sq = vx * vx + vy * vy
    ok = r_sq > _EPS_SQ
    safe_vx = jnp.where(ok, jnp.abs(vx), 1.0)
    safe_vy = jnp.where(ok, vy, 0.0)
    inv_r = lax.rsqrt(jnp.where(ok, r_sq, 1.0))
    # On the axis α is undefined; any value works because the scaled offset is zero there.
    cos_a = jnp.where(ok, safe_vy * inv_r, 1.0)
    sin_a = jnp.where(ok, safe_vx * inv_r, 0.0)
    alpha = jnp.where(ok, jnp.arctan2(safe_vx, safe_vy), 0.0)
    return cos_a, sin_a, alpha / math.pi


# ----------------------------------------------------------------------------------------------
# envelopes (Eq. 5.8-5.12)
# ----------------------------------------------------------------------------------------------


def radial_scale(
    style: Style, x: jax.Array, cos_a, sin_a, alpha_n, bend: jax.Array, twist: jax.Array
) -> jax.Array:
    """Radial scale ``S_rs(x, α, β, γ)`` (Eq. 5.9).

    Args:
        style: the style.
        x: () spline parameter.
        cos_a, sin_a, alpha_n: ``cos α``, ``|sin α|`` and ``α/π`` of the vertex.
        bend: () ``β/π`` in [0, 1].
        twist: () ``|γ|/π``.

    Returns:
        () scale, 1 for identity textures (Eq. 5.10).
    """
    t = sample_texture(style.textures, x, alpha_n)
    w = jnp.stack([jnp.maximum(-cos_a, 0.0) * bend, sin_a * bend, twist])
    return _blend(t, w)


def rect_scale(style: Style, x: jax.Array, cos_a, bend: jax.Array, twist: jax.Array):
    """Rectangular scales ``(S_l, S_f)`` (Eq. 5.12), 1 for identity curves.

    Args:
        style: the style.
        x: () spline parameter.
        cos_a: ``cos α`` of the vertex.
        bend: () ``β/π``.
        twist: () ``|γ|/π``.

    Returns:
        ``S_l`` (scales ``v'_x``, along ``b_N``) and ``S_f`` (scales ``v'_y``, along ``b_B``).
    """
    c = sample_curve(style.curves, x)
    w_f = jnp.maximum(-cos_a, 0.0) * bend
    s_f = _blend(jnp.stack([c[0], c[2]]), jnp.stack([w_f, twist]))
    s_l = _blend(jnp.stack([c[1], c[2]]), jnp.stack([bend, twist]))
    return s_l, s_f


def apply_style(
    style: Style,
    local: jax.Array,
    local_normal: jax.Array,
    x: jax.Array,
    bend: jax.Array,
    twist: jax.Array,
    *,
    radial: bool = True,
    rect: bool = True,
) -> tuple[jax.Array, jax.Array]:
    """``D_rect(D_rad(v'))`` in spline space (Eq. 5.8, 5.11, 5.13), with the hollow offset.

    Normals are multiplied by the inverse of the local cross-section scaling, which ignores the
    derivative of the scale along the surface (recompute normals from faces for exact ones).

    Args:
        style: the style.
        local: (3,) ``v'``.
        local_normal: (3,) normal in spline space.
        x: () spline parameter.
        bend: () ``β/π``.
        twist: () ``|γ|/π``.
        radial: apply ``D_rad``.
        rect: apply ``D_rect``.

    Returns:
        Deformed ``v'`` (3,) and normal (3,) (not normalized).
    """
    cos_a, sin_a, alpha_n = _cross_section(local, style.hollow)
    sx = jnp.float32(1.0)
    sy = jnp.float32(1.0)
    if radial:
        s = radial_scale(style, x, cos_a, sin_a, alpha_n, bend, twist)
        sx, sy = sx * s, sy * s
    if rect:
        s_l, s_f = rect_scale(style, x, cos_a, bend, twist)
        sx, sy = sx * s_l, sy * s_f
    deformed = jnp.stack([local[0] * sx, (local[1] - style.hollow) * sy + style.hollow, local[2]])
    # inverse-transpose of diag(sx, sy, 1); scales are > 0 for non-negative, non-zero styles
    safe_sx = jnp.where(sx > 1e-6, sx, 1.0)
    safe_sy = jnp.where(sy > 1e-6, sy, 1.0)
    normal = jnp.stack([local_normal[0] / safe_sx, local_normal[1] / safe_sy, local_normal[2]])
    return deformed, normal


# ----------------------------------------------------------------------------------------------
# inputs of Eq. 5.13: which envelopes, and the pose weights of one spline
# ----------------------------------------------------------------------------------------------


def _pose_weights(points: jax.Array, twist: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``β/π`` and ``|γ|/π`` of one spline."""
    return bend_angle(points) / math.pi, jnp.abs(twist) / math.pi


def _style_flags(styles: str) -> tuple[bool, bool]:
    if styles not in ("none", "radial", "rect", "both"):
        raise ValueError(f"styles must be 'none', 'radial', 'rect' or 'both', got {styles!r}")
    return styles in ("radial", "both"), styles in ("rect", "both")
