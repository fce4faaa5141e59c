"""Fast computation with sampled spline matrices (thesis 5.8, Fig. 5.13-5.15).

Pass 1 (:func:`sample_spline_frames`) evaluates every spline's matrices at S uniform parameters;
pass 2 (:func:`skin_vertex_sampled`, :func:`style_offset_sampled`) interpolates them per vertex.

**Fast path layout.** Pass 1 folds the bind frames into ``B'' = B B'^{-1}`` per sample (Eq. 5.7
says it may be precomputed) and stores each sample with its slope to the next one, and the
binding folds spline index and ``x`` into one coordinate ``u``; pass 2 then reads per influence
exactly what matrix skinning reads (one index-like value, one weight) plus one table row.  The
style on the dominant spline (thesis 5.8.2) is added as ``w_d R_d (D(v'_d) - v'_d)``, which equals
Eq. 5.13 with the style on that spline only.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxgfx._src.checks import check_int, checking, require_finite, require_values
from jaxgfx._src.skin.binding import SkinBinding
from jaxgfx._src.skin.geometry import _compose
from jaxgfx._src.skin.kernels import (
    blend_skin,
    blend_skin_styled,
    normalize_rows,
    style_rotation_table,
    style_scalars,
)
from jaxgfx._src.skin.rig import SplinePose, SplineRig, validate_pose
from jaxgfx._src.skin.spline import frame_inverse, spline_frames
from jaxgfx._src.skin.styles import Style, _check_style, _pose_weights, _style_flags, apply_style

__all__ = [
    "SampledBinding",
    "prepare_sampled",
    "sample_spline_frames",
    "skin_vertex_sampled",
    "style_offset_sampled",
    "skin_sampled",
    "skin_sampled_tables",
]


# ----------------------------------------------------------------------------------------------
# binding layout (Fig. 5.13)
# ----------------------------------------------------------------------------------------------


class SampledBinding(NamedTuple):
    """A binding laid out for the sampled fast path (thesis 5.8.2, Fig. 5.13), for S samples.

    Spline index and parameter are folded into one table coordinate ``u = k S + x (S - 1)``
    (row ``floor(u)``, interpolation weight ``u - floor(u)``), so pass 2 reads as many values per
    influence as matrix skinning reads (index, weight).  The style, applied to the dominant spline
    only (thesis 5.8.2), needs that spline's ``v'`` alone.
    """

    coord: jax.Array  # shape=(V, I), dtype=float32, u = spline * S + x * (S - 1)
    weight: jax.Array  # shape=(V, I), dtype=float32, skinning weights
    rest: jax.Array  # shape=(V, 3), dtype=float32, bind position v
    rest_normal: jax.Array  # shape=(V, 3), dtype=float32, bind normal
    dominant_coord: jax.Array  # shape=(V,), dtype=float32, u of the largest-weight influence
    dominant_weight: jax.Array  # shape=(V,), dtype=float32, its weight
    dominant_local: jax.Array  # shape=(V, 3), dtype=float32, its v'
    dominant_local_normal: jax.Array  # shape=(V, 3), dtype=float32, its spline-space normal


def prepare_sampled(binding: SkinBinding, samples: int = 32) -> SampledBinding:
    """Lay a :class:`SkinBinding` out for the sampled path with ``samples`` per spline."""
    samples = check_int("samples", samples, low=2)
    coord = binding.spline.astype(jnp.float32) * samples + binding.x * (samples - 1)
    dom = jnp.argmax(binding.weight, axis=1)
    take = lambda a: jnp.take_along_axis(a, dom[:, None], axis=1)[:, 0]  # noqa: E731
    take3 = lambda a: jnp.take_along_axis(a, dom[:, None, None], axis=1)[:, 0]  # noqa: E731
    return SampledBinding(
        coord=coord,
        weight=binding.weight,
        rest=binding.rest,
        rest_normal=binding.rest_normal,
        dominant_coord=take(coord),
        dominant_weight=take(binding.weight),
        dominant_local=take3(binding.local),
        dominant_local_normal=take3(binding.local_normal),
    )


# ----------------------------------------------------------------------------------------------
# pass 1 (thesis 5.8.1)
# ----------------------------------------------------------------------------------------------


def _with_slopes(values: jax.Array) -> jax.Array:
    """(K, S, C) samples -> (K * S, 2C) rows ``[m_s | m_{s+1} - m_s]`` (slope 0 at each end).

    Pass 2 then interpolates with one row read per influence (thesis Fig. 5.15 texture filtering).
    """
    k, s, c = values.shape
    slope = jnp.concatenate([values[:, 1:] - values[:, :-1], jnp.zeros((k, 1, c))], axis=1)
    return jnp.concatenate([values, slope], axis=-1).reshape(k * s, 2 * c)


def sample_spline_frames(
    rig: SplineRig, pose: SplinePose, samples: int = 32
) -> tuple[jax.Array, jax.Array]:
    """Pass 1 (thesis 5.8.1): every spline's matrices at ``samples`` uniform ``x``.

    Args:
        rig: the rig.
        pose: the pose.
        samples: S >= 2 samples per spline.

    Returns:
        ``skinning`` (K * S, 24): ``B''(x_s) = B(x_s) B'(x_s)^{-1}`` (Eq. 5.7) as 12 values
        (columns of ``[R | t]``) and the slope to the next sample; ``style`` (K * S, 20): the pose
        rotation ``[b_N | b_B | b_T]`` (9 values) and its slope, then ``β/π`` and ``|γ|/π``.
    """
    samples = check_int("samples", samples, low=2)
    xs = jnp.linspace(0.0, 1.0, samples)
    posed = spline_frames(rig, pose, xs)
    bound = spline_frames(rig, rig.bind, xs)
    rel = jax.vmap(jax.vmap(lambda p, b: _compose(p, frame_inverse(b))))(posed, bound)
    k = posed.shape[0]
    skinning = _with_slopes(jnp.swapaxes(rel, -1, -2).reshape(k, samples, 12))
    rot = _with_slopes(jnp.swapaxes(posed[..., :3], -1, -2).reshape(k, samples, 9))
    bend, twist = jax.vmap(_pose_weights)(pose.points, pose.twist)
    pw = jnp.repeat(jnp.stack([bend, twist], -1), samples, axis=0)
    return skinning, jnp.concatenate([rot, pw], axis=-1)


# ----------------------------------------------------------------------------------------------
# pass 2 (thesis 5.8.2)
# ----------------------------------------------------------------------------------------------


def _lerp(table: jax.Array, coord: jax.Array, width: int) -> jax.Array:
    """Row ``floor(u)`` plus ``frac(u)`` times its slope: (..., width)."""
    r0 = jnp.floor(coord)
    t = coord - r0
    rows = table[r0.astype(jnp.int32)]
    return rows[..., :width] + t[..., None] * rows[..., width : 2 * width]


def skin_vertex_sampled(
    skinning: jax.Array,
    coord: jax.Array,
    weight: jax.Array,
    vertex: jax.Array,
    normal: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """Pass 2 (thesis 5.8.2) without styles: ``Σ w_i B''_i(x_i) v`` (Eq. 5.7) like matrix skinning.

    Args:
        skinning: (K * S, 24) table from :func:`sample_spline_frames`.
        coord: (I,) table coordinates ``u``.
        weight: (I,) weights.
        vertex, normal: (3,) bind position and unit normal.

    Returns:
        Position (3,) and unit normal (3,).
    """
    m = jnp.dot(weight, _lerp(skinning, coord, 12))  # blend first, then one affine map, as SSD
    pos = m[0:3] * vertex[0] + m[3:6] * vertex[1] + m[6:9] * vertex[2] + m[9:12]
    nrm = m[0:3] * normal[0] + m[3:6] * normal[1] + m[6:9] * normal[2]
    return pos, normalize_rows(nrm)


def style_offset_sampled(
    style_table: jax.Array,
    style: Style,
    samples: int,
    coord: jax.Array,
    weight: jax.Array,
    local: jax.Array,
    local_normal: jax.Array,
    *,
    radial: bool = True,
    rect: bool = True,
) -> tuple[jax.Array, jax.Array]:
    """Style of the dominant spline as a world-space offset (thesis 5.8.2, Eq. 5.13).

    With the style on one influence ``d`` only, Eq. 5.13 equals the plain skin plus
    ``w_d R_d(x_d) (D(v'_d) - v'_d)``, since ``B_d v'_d = B''_d v``.

    Args:
        style_table: (K * S, 20) from :func:`sample_spline_frames`.
        style: the style.
        samples: S.
        coord: () table coordinate of the dominant influence.
        weight: () its weight.
        local, local_normal: (3,) its ``v'`` and spline-space normal.
        radial, rect: which envelopes to apply.

    Returns:
        Position offset (3,) and normal offset (3,).
    """
    row = _lerp(style_table, coord, 9)
    r0 = jnp.floor(coord)
    spline_start = jnp.floor(r0 / samples) * samples
    x = (coord - spline_start) / (samples - 1)
    params = style_table[r0.astype(jnp.int32), 18:20]
    sv, sn = apply_style(
        style, local, local_normal, x, params[0], params[1], radial=radial, rect=rect
    )
    dv = sv - local
    dn = sn - local_normal
    pos = row[0:3] * dv[0] + row[3:6] * dv[1] + row[6:9] * dv[2]
    nrm = row[0:3] * dn[0] + row[3:6] * dn[1] + row[6:9] * dn[2]
    return weight * pos, weight * nrm


def skin_sampled(
    rig: SplineRig,
    pose: SplinePose,
    binding: SampledBinding,
    style: Style | None = None,
    *,
    samples: int = 32,
    styles: str = "none",
    subrows: int | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Two-pass sampled spline skinning of a mesh (thesis 5.8), style on the dominant spline.

    Pass 1 (:func:`sample_spline_frames`) then pass 2 (:func:`skin_sampled_tables`).

    Args:
        rig: the rig.
        pose: the pose.
        binding: from :func:`prepare_sampled` with the same ``samples``.
        style: the style (needed unless ``styles == 'none'``).
        samples: S per spline.
        styles: 'none', 'radial', 'rect' or 'both'.
        subrows: see :func:`skin_sampled_tables`.

    Returns:
        Positions (V, 3) and unit normals (V, 3).
    """
    _check_pass2(binding, style, styles)
    validate_pose(rig, pose, where="skin_sampled")
    pose = jax.tree_util.tree_map(jnp.asarray, pose)
    skinning, style_table = sample_spline_frames(rig, pose, samples)
    return skin_sampled_tables(
        skinning, style_table, binding, style, samples=samples, styles=styles, subrows=subrows
    )


def _check_pass2(binding, style, styles: str) -> tuple[bool, bool]:
    radial, rect = _style_flags(styles)
    if (radial or rect) and style is None:
        raise ValueError("style is required when styles != 'none'")
    if not isinstance(binding, SampledBinding):
        raise TypeError("binding must be a SampledBinding (use prepare_sampled)")
    return radial, rect


def _require_pass2(skinning, style_table, binding: SampledBinding, styled: bool) -> None:
    """Inside :func:`~jaxgfx.checks.checked`: the values pass 2 would turn into wrong vertices.

    A table coordinate outside the table is clamped by the gathers (the vertex follows
    another spline's end), a NaN row, weight or bind position moves its vertices to NaN.
    """
    if not checking():
        return
    where = "skin_sampled_tables"
    rows = skinning.shape[0]
    require_finite("skinning", skinning, where)
    if styled:
        require_finite("style_table", style_table, where)
    for name in ("coord", "dominant_coord"):
        u = jnp.asarray(getattr(binding, name))
        rule = f"{{}} is outside the table's rows [0, {rows - 1}]"
        require_values(f"binding.{name}", (u >= 0) & (u <= rows - 1), u, rule, where)
    for name in ("weight", "rest", "rest_normal", "dominant_weight"):
        require_finite(f"binding.{name}", getattr(binding, name), where)
    if styled:
        for name in ("dominant_local", "dominant_local_normal"):
            require_finite(f"binding.{name}", getattr(binding, name), where)


def skin_sampled_tables(
    skinning: jax.Array,
    style_table: jax.Array,
    binding: SampledBinding,
    style: Style | None = None,
    *,
    samples: int = 32,
    styles: str = "none",
    subrows: int | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Pass 2 of :func:`skin_sampled` alone, from pass 1's tables.

    For a batch of poses split over devices, pass 1 (about 45 small ops per pose) can then run
    vmapped over each device's whole shard once and only this per-vertex pass in chunks
    (``jaxgfx.sweep.sharded_vmap(..., chunk=8)``), as ``experiments/skinning_bench.py`` does;
    a fitting loop over fixed poses computes pass 1 once for all steps.

    Args:
        skinning: (K * S, 24) and ``style_table`` (K * S, 20): :func:`sample_spline_frames`.
        style_table: see ``skinning`` (unused when ``styles == 'none'``).
        binding: from :func:`prepare_sampled` with the same ``samples``.
        style: the style (needed unless ``styles == 'none'``).
        samples: S per spline.
        styles: 'none', 'radial', 'rect' or 'both'.
        subrows: None interpolates each influence's row and slope per vertex (the reference,
            :func:`skin_vertex_sampled`).  Q >= 1 moves that interpolation into the table: it is
            expanded to Q sub-rows per sample (``m_s + (q / Q) s_s``, a per-pose lerp of S Q
            rows) and every influence reads its nearest sub-row, ``u`` rounded to ``1/Q`` of a
            sample step, with the LBS kernel's arithmetic (one table read per coefficient and
            influence instead of two).  Equals :func:`skin_vertex_sampled` at the rounded
            ``u``: faster, at a larger deviation from exact skinning (see the design notes,
            docs/design/skin.md).
            The style offsets likewise read the dominant spline's rotation from sub-rows
            (:func:`style_offset_sampled` at the rounded ``u``).

    Returns:
        Positions (V, 3) and unit normals (V, 3).  With styles, the blend plus
        :func:`style_offset_sampled`'s offsets; the normal is the raw blended normal plus the
        normal offset, normalized once (Eq. 5.13, as ``skin_exact``), both computed in the
        blend loops of the mesh kernel.
    """
    radial, rect = _check_pass2(binding, style, styles)
    samples = check_int("samples", samples, low=2)
    if subrows is not None:
        subrows = check_int("subrows", subrows, low=1)
    if skinning.ndim != 2 or skinning.shape[1] != 24 or skinning.shape[0] % samples:
        raise ValueError(f"skinning must have shape (K * {samples}, 24), got {skinning.shape}")
    if style_table.shape != (skinning.shape[0], 20):
        raise ValueError(
            f"style_table must have shape ({skinning.shape[0]}, 20), got {style_table.shape}"
        )
    _require_pass2(skinning, style_table, binding, radial or rect)
    # skin_vertex_sampled over the vertices, in the structure-of-arrays kernel (kernels.py)
    coord = jnp.asarray(binding.coord).T
    weight = jnp.asarray(binding.weight).T
    rest, rest_normal = jnp.asarray(binding.rest).T, jnp.asarray(binding.rest_normal).T
    if radial or rect:
        assert style is not None  # _check_pass2
        style = jax.tree_util.tree_map(jnp.asarray, style)
        _check_style(style, "skin_sampled_tables")
    dom = (
        jnp.asarray(binding.dominant_coord),
        jnp.asarray(binding.dominant_weight),
        jnp.asarray(binding.dominant_local),
        jnp.asarray(binding.dominant_local_normal),
    )
    if subrows is None:
        row = jnp.floor(coord)
        index, frac = row.astype(jnp.int32), coord - row
        if not (radial or rect):
            return blend_skin(skinning.T, index, weight, frac, rest, rest_normal)
        # style_offset_sampled as one more term of the blend loops (blend_skin_styled): a
        # small pass writes the (4, V) in-plane offsets, the loops read the dominant spline's
        # rotation (row and slope); the normal offset joins the raw blend, normalized once
        # (Eq. 5.13, as skin_exact); no (V, 3) offsets are written and read again.
        assert style is not None
        drow, dt, _, d = style_scalars(
            style_table, style, samples, *dom, radial=radial, rect=rect, subrows=None
        )
        rot = style_rotation_table(style_table, None)
        return blend_skin_styled(
            skinning.T, index, weight, frac, rest, rest_normal, rot, drow, dt, d
        )
    # sub-row q of sample s is m_s + (q / Q) s_s: the table is (12, K S Q), read as LBS's;
    # u stays below K S, so the rounded index never reaches the next spline's first row
    f = jnp.arange(subrows, dtype=skinning.dtype) / subrows
    sub = skinning[:, None, :12] + f[None, :, None] * skinning[:, None, 12:]
    sub_index = jnp.round(coord * subrows).astype(jnp.int32)
    # written out once per pose: fused into the gathers, every read would redo the lerp
    table = lax.optimization_barrier(sub.reshape(-1, 12).T)
    if not (radial or rect):
        return blend_skin(table, sub_index, weight, None, rest, rest_normal)
    # the style offset as one more term of the blend loops (blend_skin_styled): a small
    # pass writes the (4, V) in-plane offsets, the rotation is read from sub-rows in the loop
    assert style is not None
    _, _, dom_sub, d = style_scalars(
        style_table, style, samples, *dom, radial=radial, rect=rect, subrows=subrows
    )
    assert dom_sub is not None
    rot = style_rotation_table(style_table, subrows)
    return blend_skin_styled(
        table, sub_index, weight, None, rest, rest_normal, rot, dom_sub, None, d
    )
