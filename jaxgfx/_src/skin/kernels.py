"""Mesh kernels for matrix-blend skinning: LBS (thesis 5.9) and sampled spline skinning (5.8.2).

Both blend 12 affine coefficients per vertex (the columns of ``[R | t]``) from a small table and
apply them to the bind position and normal.  The per-vertex references (:func:`lbs_vertex`,
:func:`skin_vertex_sampled`) read as the thesis writes them; vmapped, XLA:CPU compiles them to a
gather of (V, I, 12) rows and a contraction, some 30x slower than the memory bound.  Here the
same arithmetic runs in a structure-of-arrays layout that XLA:CPU fuses into a few loops:

* the table is stored as coefficient columns (12 or 24, R), so one influence's coefficient is a
  scalar gather ``columns[c][index[i]]`` of a (V,) index array;
* the 12 blended coefficients are (V,) arrays, applied to the (V,) arrays x, y, z;
* every gather has exactly one consumer.  XLA:CPU does not fuse a gather whose result has several
  users (it writes each one out, 36-48 passes over V), so positions and normals take their own
  gathers: ``optimization_barrier`` on the indices keeps CSE from merging the two sets.

Measured on a 2-core box (1 M vertices, 4 influences, 64 bones, positions and normals, one pose;
compile excluded, medians of 7 interleaved repeats; separate runs under varying load, except that
the 196, 65 and 43 ms come from one run):

* vmap of the per-vertex reference: 196-232 ms;
* one-hot (V, J) @ (J, 12): 647 ms; one (V, 12) row gather per influence: 177 ms;
* SoA gathers whose coefficients feed both positions and normals: 126-191 ms (XLA writes each
  multi-use gather out: 36-48 loops); the same with the (12, V) coefficients materialized: 91 ms;
* this kernel with (3, V) outputs transposed to (V, 3): 65 ms; stacked last (kept): 43 ms.

A select chain over the J table rows instead of each gather (``where(index == j, col[j], ...)``)
is shape-dependent: 21.6 against 36.9 ms for the bench's 80 poses x 12,546 vertices with J = 6
(the comparisons are pose-independent and hoisted), but 103 against 28 ms for one pose of 1 M
vertices with J = 6 and 350 against 33 ms with J = 24: dropped.
Packing two coefficients (LBS) or a row and its slope (sampled) into one complex64 gather halves
the gathers but not the time: 50.2 against 56.1 ms (LBS) and 83.7 against 86.8 ms (sampled), 80
poses x 12,546 vertices: dropped.
For the sampled table, interpolating rows ``r`` and ``r + 1`` as 2I plain influences instead of
row plus slope saved 6-10 % (56-59 against 63 ms, 80 poses x 12,546 vertices): not kept, the
kernel keeps the reference's arithmetic.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxgfx._src.skin.geometry import _EPS_SQ

__all__ = ["blend_skin"]


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
        is faster than stacking (3, V) and transposing, 47 against 66 ms for 80 x 12,546).
    """
    m = _coefficients(columns, index, weight, frac)
    px, py, pz = _linear(m, vertices)
    pos = jnp.stack([px + m[9], py + m[10], pz + m[11]], axis=-1)
    # fresh gathers for the normals: one consumer per gather, so each set fuses into one loop
    index, weight, frac = lax.optimization_barrier((index, weight, frac))
    nx, ny, nz = _linear(_coefficients(columns, index, weight, frac), normals)
    s = lax.rsqrt(jnp.maximum(nx * nx + ny * ny + nz * nz, _EPS_SQ))
    return pos, jnp.stack([nx * s, ny * s, nz * s], axis=-1)
