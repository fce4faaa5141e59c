"""Mesh kernels for matrix-blend skinning: LBS (thesis 5.9) and sampled spline skinning (5.8.2).

Both blend 12 affine coefficients per vertex (the columns of ``[R | t]``) from a small table and
apply them to the bind position and normal.  The per-vertex references (:func:`lbs_vertex`,
:func:`skin_vertex_sampled`) read as the thesis writes them; vmapped, XLA:CPU compiles them to a
gather of (V, I, 12) rows and a contraction, far from the memory bound.  Here the same
arithmetic runs in a structure-of-arrays layout that XLA:CPU fuses into a few loops:

* the table is stored as coefficient columns (12 or 24, R), so one influence's coefficient is a
  scalar gather ``columns[c][index[i]]`` of a (V,) index array;
* the 12 blended coefficients are (V,) arrays, applied to the (V,) arrays x, y, z;
* every gather has exactly one consumer: XLA:CPU does not fuse a gather whose result has several
  users (it writes each one out), so positions and normals take their own gathers, and
  ``optimization_barrier`` on the indices keeps CSE from merging the two sets;
* outputs are stacked last, (V, 3), and normals are normalized in a second pass over the
  written-out raw normals (fused into the gather loop, each component would recompute all
  three for the length).

Sampled spline skinning reads a row and its slope per coefficient and influence
(:func:`blend_skin` with ``frac``); with sub-rows (``skin_sampled(..., subrows=Q)``) pass 1
expands the table to Q rows per sample, so pass 2 is the LBS kernel reading the nearest sub-row.
Deformation styles fold into the same loops (:func:`blend_skin_styled`): a small pass writes the
in-plane offsets per pose (:func:`style_scalars`) and the loops add the dominant spline's
rotation of them as one more influence, normalizing the styled normal once (Eq. 5.13).  The
designs measured against these, and the numbers, are in the design notes
(``docs/design/skin.md``; ``python -m experiments.skinning_bench``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxgfx._src.skin.geometry import _EPS_SQ
from jaxgfx._src.skin.styles import Style, _cross_section, sample_curve, sample_texture

__all__ = [
    "blend_skin",
    "blend_skin_styled",
    "normalize_rows",
    "style_offsets",
    "style_scalars",
    "style_rotation_table",
    "style_subrow_table",
]


def _coefficients(columns, index, weight, frac) -> list[jax.Array]:
    """The 12 blended coefficients ``Σ_i w_i (m_c[r_i] + f_i s_c[r_i])``, each (V,)."""
    m: list[jax.Array] = []
    for c in range(12):
        acc = None
        for i in range(index.shape[0]):
            g = columns[c][index[i]]
            if frac is not None:
                g = g + frac[i] * columns[12 + c][index[i]]
            term = weight[i] * g
            acc = term if acc is None else acc + term
        assert acc is not None
        m.append(acc)
    return m


def _linear(m: list[jax.Array], p: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    x, y, z = p[0], p[1], p[2]
    return (
        m[0] * x + m[3] * y + m[6] * z,
        m[1] * x + m[4] * y + m[7] * z,
        m[2] * x + m[5] * y + m[8] * z,
    )


def blend_skin(
    columns: jax.Array,
    index: jax.Array,
    weight: jax.Array,
    frac: jax.Array | None,
    vertices: jax.Array,
    normals: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """Blend-then-apply skinning of a mesh in structure-of-arrays layout.

    Args:
        columns: (12, R) coefficient columns (columns of ``[R | t]`` per table row), or (24, R)
            with the slope to the next row in rows 12-23 (sampled spline table).
        index: (I, V) int32 table rows.
        weight: (I, V) weights.
        frac: (I, V) interpolation parameter along the slope, or None (plain LBS).
        vertices: (3, V) bind positions.
        normals: (3, V) bind normals.

    Returns:
        Positions (V, 3) and unit normals (V, 3) (stacked last: under ``vmap`` over poses this
        is faster than stacking (3, V) and transposing).
    """
    m = _coefficients(columns, index, weight, frac)
    px, py, pz = _linear(m, vertices)
    pos = jnp.stack([px + m[9], py + m[10], pz + m[11]], axis=-1)
    # fresh gathers for the normals: one consumer per gather, so each set fuses into one loop
    index, weight, frac = lax.optimization_barrier((index, weight, frac))
    raw = jnp.stack(_linear(_coefficients(columns, index, weight, frac), normals), axis=-1)
    # Normalize in a second pass over the written (V, 3) normals.  Fused into the gather loop,
    # every output component would recompute all three components for the length (3x the
    # normal's gathers).
    return pos, normalize_rows(lax.optimization_barrier(raw))


def normalize_rows(raw: jax.Array) -> jax.Array:
    """``raw / |raw|`` row-wise for written-out (..., 3) normals (length floored at ``_EPS``).

    Args:
        raw: (..., 3) normals, already written out (behind an ``optimization_barrier``): fused
            into a gather loop, every component would recompute all three for the length.

    Returns:
        (..., 3) unit normals.
    """
    nx, ny, nz = raw[..., 0], raw[..., 1], raw[..., 2]
    s = lax.rsqrt(jnp.maximum(nx * nx + ny * ny + nz * nz, _EPS_SQ))
    return jnp.stack([nx * s, ny * s, nz * s], axis=-1)


def style_offsets(
    style_table: jax.Array,
    style: Style,
    samples: int,
    coord: jax.Array,
    weight: jax.Array,
    local: jax.Array,
    local_normal: jax.Array,
    *,
    radial: bool,
    rect: bool,
    subrows: int | None = None,
) -> tuple[jax.Array, jax.Array]:
    """:func:`style_offset_sampled` of every vertex in structure-of-arrays layout.

    What does not depend on the pose (the cross-section angle, the texture and curve samples at
    the vertex's ``x`` and ``α``) is the per-vertex reference's arithmetic vmapped over the
    vertices; under ``vmap`` over poses it is computed once.  Per pose the kernel gathers the
    dominant spline's pose weights and interpolated rotation as (V,) scalars, as
    :func:`blend_skin` does, with fresh gathers for the normal offset.

    Args:
        style_table: (K * S, 20) style table from :func:`sample_spline_frames`.
        style: the style.
        samples: S.
        coord: (V,) table coordinate of each vertex's dominant influence.
        weight: (V,) its weight.
        local, local_normal: (V, 3) its ``v'`` and spline-space normal.
        radial, rect: which envelopes to apply.
        subrows: None interpolates the rotation per vertex; Q rounds ``coord`` to ``1/Q`` of a
            sample step and reads the rotation from a table expanded to Q sub-rows per sample
            (one gather per value instead of two; as ``skin_sampled_tables(subrows=Q)``).

    Returns:
        Position offsets (V, 3) and normal offsets (V, 3), as the reference's (at the rounded
        ``coord`` with ``subrows``).
    """
    row, t, sub, d = style_scalars(
        style_table,
        style,
        samples,
        coord,
        weight,
        local,
        local_normal,
        radial=radial,
        rect=rect,
        subrows=subrows,
        written=False,
    )
    rotation = style_rotation_table(style_table, subrows)
    dom, dom_t = (row, t) if sub is None else (sub, None)

    def rotate(dom, dom_t, d0, d1):
        # R(x) (d0, d1, 0): the third column meets a zero (styles leave v'_z alone)
        rc = [_rotation_value(rotation, dom, dom_t, c) for c in range(6)]
        return jnp.stack([rc[k] * d0 + rc[3 + k] * d1 for k in range(3)], axis=-1)

    dpos = rotate(dom, dom_t, d[0], d[1])
    # fresh gathers for the normals (one consumer per gather, see blend_skin)
    dom, dom_t = lax.optimization_barrier((dom, dom_t))
    return dpos, rotate(dom, dom_t, d[2], d[3])


def _rotation_value(rotation: jax.Array, dom: jax.Array, t: jax.Array | None, c: int):
    """Value ``c`` (0-5) of the dominant rotation at rows ``dom``, lerped by ``t`` if given."""
    g = rotation[c][dom]
    return g if t is None else g + t * rotation[6 + c][dom]


def style_rotation_table(style_table: jax.Array, subrows: int | None) -> jax.Array:
    """The style rotation's first two columns as read per vertex, written out once.

    Args:
        style_table: (K * S, 20) style table from :func:`sample_spline_frames`.
        subrows: None for (12, K S): ``b_N``, ``b_B`` per sample and, in rows 6-11, their
            slopes to the next sample; Q for :func:`style_subrow_table`'s (6, K S Q).
    """
    if subrows is not None:
        return style_subrow_table(style_table, subrows)
    cols = style_table.T  # (20, R): 9 rotation values, their slopes, bend, twist
    return lax.optimization_barrier(jnp.concatenate([cols[0:6], cols[9:15]]))


def style_subrow_table(style_table: jax.Array, subrows: int) -> jax.Array:
    """(6, K S Q) sub-row table of the style rotation's first two columns, written out once.

    Args:
        style_table: (K * S, 20) style table from :func:`sample_spline_frames`.
        subrows: Q sub-rows per sample (``b_s + (q / Q) slope_s``).

    Returns:
        (6, K S Q): ``b_N`` and ``b_B`` at every sub-row, one (K S Q,) column per value.
    """
    cols = style_table.T
    f_sub = jnp.arange(subrows, dtype=style_table.dtype) / subrows
    return lax.optimization_barrier(
        jnp.stack([(cols[c][:, None] + f_sub * cols[9 + c][:, None]).reshape(-1) for c in range(6)])
    )


def style_scalars(
    style_table: jax.Array,
    style: Style,
    samples: int,
    coord: jax.Array,
    weight: jax.Array,
    local: jax.Array,
    local_normal: jax.Array,
    *,
    radial: bool,
    rect: bool,
    subrows: int | None = None,
    written: bool = True,
) -> tuple[jax.Array, jax.Array, jax.Array | None, jax.Array]:
    """The per-pose scalars of :func:`style_offsets`: rows and the weighted in-plane offsets.

    The offset is ``R(x) d`` with ``d = w (D(v') - v')`` in the rotation's first two columns
    (styles leave ``v'_z`` alone), so one pass can write ``d`` for positions and normals as a
    (4, V) array and the rotation be applied where it is read (:func:`blend_skin_styled`).

    Args:
        style_table, style, samples, coord, weight, local, local_normal, radial, rect, subrows:
            as :func:`style_offsets`.
        written: True writes ``d`` out behind a barrier (for a loop that reads it with
            gathers); False leaves it to fuse into its consumers (:func:`style_offsets`, where
            a fit that uses the positions alone then never computes the normal's part).

    Returns:
        ``row`` (V,) int32 and ``t`` (V,) of the (rounded) coordinate, the sub-row index (V,)
        int32 (None without ``subrows``), and ``d`` (4, V): ``w dx, w dy`` of the position and
        ``w dnx, w dny`` of the normal, written out behind a barrier.
    """
    cols = style_table.T  # (20, R): 9 rotation values, their slopes, bend, twist
    sub = None
    if subrows is not None:
        sub = jnp.round(coord * subrows).astype(jnp.int32)
        coord = sub.astype(coord.dtype) / subrows  # exact for Q a power of 2
    r0 = jnp.floor(coord)
    t = coord - r0
    row = r0.astype(jnp.int32)
    x = (coord - jnp.floor(r0 / samples) * samples) / (samples - 1)
    cos_a, sin_a, alpha_n = jax.vmap(_cross_section, in_axes=(0, None))(local, style.hollow)
    tex = (
        jax.vmap(sample_texture, in_axes=(None, 0, 0))(style.textures, x, alpha_n)
        if radial
        else None
    )
    crv = jax.vmap(sample_curve, in_axes=(None, 0))(style.curves, x) if rect else None
    front = jnp.maximum(-cos_a, 0.0)

    def factors(row) -> list[jax.Array]:
        """The envelope factors of ``sx = s_rad s_l`` and ``sy = s_rad s_f``, each (V,)."""
        bend, twist = cols[18][row], cols[19][row]
        out = []
        if radial:
            assert tex is not None
            w0, w1 = front * bend, sin_a * bend
            w_sum = w0 + w1 + twist
            out.append(
                (w0 * tex[:, 0] + w1 * tex[:, 1] + twist * tex[:, 2]) / jnp.maximum(1.0, w_sum)
                + jnp.maximum(1.0 - w_sum, 0.0)
            )
        if rect:
            assert crv is not None
            out.append(_blend2(crv[:, 1], crv[:, 2], bend, twist))  # s_l
            out.append(_blend2(crv[:, 0], crv[:, 2], front * bend, twist))  # s_f
        return out

    # The factors once per vertex and pose, written out as one (F, V) array: fused into the
    # rotation (or stacked with the offsets), every output component recomputes them and their
    # gathers (4 to 6 times).
    fs = factors(row)
    if not fs:
        raise ValueError("style_offsets: radial or rect must be True")
    f = lax.optimization_barrier(jnp.stack(fs))
    one = jnp.float32(1.0)
    s_rad = f[0] if radial else one
    sx = s_rad * (f[-2] if rect else one)
    sy = s_rad * (f[-1] if rect else one)
    h = style.hollow
    lx, ly = local[:, 0], local[:, 1]
    nx, ny = local_normal[:, 0], local_normal[:, 1]
    safe_sx = jnp.where(sx > 1e-6, sx, 1.0)
    safe_sy = jnp.where(sy > 1e-6, sy, 1.0)
    d = jnp.stack(
        [
            weight * (lx * sx - lx),
            weight * (((ly - h) * sy + h) - ly),
            weight * (nx / safe_sx - nx),
            weight * (ny / safe_sy - ny),
        ]
    )
    return row, t, sub, lax.optimization_barrier(d) if written else d


def blend_skin_styled(
    columns: jax.Array,
    index: jax.Array,
    weight: jax.Array,
    frac: jax.Array | None,
    vertices: jax.Array,
    normals: jax.Array,
    rotation: jax.Array,
    dominant: jax.Array,
    dominant_frac: jax.Array | None,
    offset: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """:func:`blend_skin` plus the style offset as one more term of the same loops.

    The offset ``R_d (d_x, d_y, 0)`` (:func:`style_scalars`) is added where the blend is
    computed, so no (V, 3) offset is written and read again and there is no extra add pass;
    the normal ``raw + R_d (d_nx, d_ny, 0)`` is normalized once (Eq. 5.13 blends the styled
    spline-space normals before normalizing, as :func:`skin_exact` does).

    Args:
        columns, index, weight, frac, vertices, normals: as :func:`blend_skin`.
        rotation: (6, R') the dominant spline's ``b_N``, ``b_B`` per row, or (12, R') with
            their slopes to the next row in rows 6-11.
        dominant: (V,) int32 row of ``rotation`` for each vertex.
        dominant_frac: (V,) interpolation parameter along the slope, or None (6 rows).
        offset: (4, V) ``w d`` of positions and normals from :func:`style_scalars`.

    Returns:
        Positions (V, 3) and unit normals (V, 3).
    """

    def add(p, dom, t, d0, d1):
        rc = [_rotation_value(rotation, dom, t, c) for c in range(6)]
        return [p[k] + rc[k] * d0 + rc[3 + k] * d1 for k in range(3)]

    m = _coefficients(columns, index, weight, frac)
    px, py, pz = add(_linear(m, vertices), dominant, dominant_frac, offset[0], offset[1])
    pos = jnp.stack([px + m[9], py + m[10], pz + m[11]], axis=-1)
    # fresh gathers for the normals (one consumer per gather, see blend_skin)
    index, weight, frac, dominant, dominant_frac = lax.optimization_barrier(
        (index, weight, frac, dominant, dominant_frac)
    )
    m = _coefficients(columns, index, weight, frac)
    raw = jnp.stack(
        add(_linear(m, normals), dominant, dominant_frac, offset[2], offset[3]), axis=-1
    )
    return pos, normalize_rows(lax.optimization_barrier(raw))


def _blend2(s0, s1, w0, w1):
    """Eq. 5.9 / 5.12's blend of two samples, as ``styles._blend``."""
    w_sum = w0 + w1
    return (w0 * s0 + w1 * s1) / jnp.maximum(1.0, w_sum) + jnp.maximum(1.0 - w_sum, 0.0)
