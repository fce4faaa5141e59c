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
row plus slope saved 6-10 % (56-59 against 63 ms, 80 poses x 12,546 vertices) in session 7, and
lost 30 % in session 9 (below): not kept, the kernel keeps the reference's arithmetic.

Session 9 (CPU time of one process, so the numbers hold on a busy box; 80 poses x 12,546
vertices vmapped, 64 bones, 4 influences unless said):

* An elemental loop computes each output element on its own, so a (V, 3) output whose every
  component needs all three (the normal's length) recomputes all of them: normalizing in the
  gather loop cost 3x the normal's gathers (31 against 15 ms for the normals with 6 bones
  and 3 influences).  The normals are now written raw and normalized in a second pass:
  52 -> 30 ms.  On one 1 M-vertex pose the fused form was as fast (26-32 ms either way).
* Gathers from a table batched over P poses read P x 12 x J floats (245 KB for 80 x 64 bones):
  vmapping all poses at once spills the table from the cache.  ``lax.map`` in chunks of 4-16
  poses: 48 -> 25-26 ms (``jaxgfx.sweep.sharded_vmap(..., chunk=)``).  Chunking the vertices of
  one pose instead (``lax.map`` over 1-16 k vertex blocks) was 3-4x slower: dropped.
* Sharing the blended coefficients of positions and normals in one (V, 6) output: 313 against
  73 ms wall on one 1 M-vertex pose (the multi-use gathers again): dropped.
* :func:`style_offsets`: the style path in this layout, 107-113 -> 57 ms for both envelopes.

Sampled skinning against LBS (issue 16's ``sampled >= 0.9x LBS``; the limb: 80 poses x 12,546
vertices, 3 influences, S = 32, 6 bones for LBS; CPU time and wall of one process, best of 7-9
interleaved rounds, one XLA device, load 3.4-4.8 on 2 cores; every variant equal to this kernel
to 1e-6).  The kept kernel runs at 0.62-0.71x LBS (34.4 against 24.5 ms CPU time at best):

* What the time goes to (the optimized LLVM IR of the position loop): XLA:CPU emits a scalar
  loop over (pose, vertex) with the 3 components unrolled, no SIMD and no FMA contraction.  Per
  vertex and pose the sampled position loop does 84 loads and ~165 float ops (72 table loads:
  row and slope of 12 coefficients for 3 influences), LBS 45 loads and ~93 ops: positions alone
  take 18.7 against 12.0 ms.  Pass 1 (the table) is 1.9 against 0.6 ms for the 80 poses.
* (a) row and slope side by side, a (12, R, 2) table with one (V, 2) gather per coefficient and
  influence: 0.70x (35.3 ms), with ``mode='promise_in_bounds'`` 0.71x: as fast as two gathers
  (the loop loads each float on its own either way).
* (b) the lerp folded into the weights (2I influences ``r``, ``r + 1`` with weights
  ``w (1 - f)``, ``w f`` of a plain 12-column table, the LBS kernel): 0.47x (52.0 ms), 0.49x
  with the 2I indices and weights precomputed: twice the index and weight loads and clamps.
* The 12 blended coefficients written out once and shared by positions and normals ((12, V) or
  (V, 12) per pose): 0.23-0.27x (106-121 ms); they are 48 MB for 80 poses, written and read.
* Positions and raw normals from the same 12 coefficients in one loop, written as one (V, 2, 3)
  or (V, 3, 2) array and split in the normalizing pass: sampled 33.5 against 34.7 ms (0.72x) and
  35.8 against 34.6 ms (0.68x); LBS in the (V, 3, 2) form took 21.2 against 24.5 ms (one run at
  load 9-10, not adopted: it would move the bar, not the ratio).
* Poses minor, a (C, R, P) table gathered as (V, P) arrays (a vertex's indices and weights are
  fixed along the minor axis), then transposed to (P, V, 3): LBS 24.9 -> 17.7 ms, sampled
  34.6 -> 35.5 ms, so 0.50x.
* On 2 devices (``sharded_vmap``, chunks of 4 / 8 / 20 / 40 poses): 0.50 / 0.45 / 0.51 / 0.45x
  the chunk-8 LBS; pass 1 runs once per chunk there (about 45 small ops each): 4.4 against
  1.4 ms.

Session 10, like for like (every kernel in chunks of 8 poses, ``sharded_vmap(chunk=8)``, as the
LBS row the target is measured against; CPU time of one process, best of 7 interleaved rounds,
80 poses x 12,546 vertices, load 3.7-8.7; every variant equal to the kept kernel to 1e-6):

* Chunks help LBS (24.4 -> 17.9 ms) and the styles (97.7 -> 65.8 ms) but not the sampled kernel
  (35.4 -> 38.3 ms): chunked against chunked, sampled runs at 0.42-0.50x LBS and spline + both
  styles at 0.27-0.30x, below the vmap-against-vmap figures above.  ``skinning_bench`` (wall,
  best of 9): sampled 0.41x on 1 device and 0.52x on 2, styles 0.30x and 0.32x at load 2.4
  (vmap against vmap in the same run: 0.57x and 0.44x); 0.48x / 0.47x and 0.30x / 0.26x at
  load 7-8.  Chunks take LBS from 22.3 to 12.4 ms there (its outputs and raw normals stay in
  cache) but the sampled kernel only from 38.9 to 30.1 ms: it is bound by its scalar arithmetic.
  ``--xla_cpu_enable_fast_math=true`` did not help (sampled / styles against LBS, chunked, CPU
  time, 2 alternating processes each at load 1-6: 0.47-0.65x / 0.29-0.45x with the flag,
  0.66-0.69x / 0.40-0.41x without).
* Pass 1 out of the chunk loop (vmapped once over a device's shard, pass 2 alone in the loop,
  :func:`~jaxgfx._src.skin.sampled.skin_sampled_tables`): 38.9 -> 36.4 ms sampled, 62.1 -> 61.0 ms
  with both styles on 2 devices; kept in the bench.  Pass 1 was not where the 2-device rows lost.
* Where spline + both styles spends its 64.8 ms (1 device, chunked; LBS 17.7): the sampled blend
  42.4, the style offsets alone 18.8, the final add and renormalization about 7 (57.8 without).
  Normalizing once (raw blend + offset in one pass, instead of blend normalized, then the sum):
  63.6-63.8 against 63.6 ms; the pose-independent style terms (cross-section angle, texture and
  curve samples) written out behind a barrier: 61.5 -> 65.6 ms (no gain; XLA already keeps them
  out of the per-pose loop).  Both dropped.
* New design, kept as an option (``skin_sampled(..., subrows=Q)``): the lerp moved from pass 2
  into pass 1.  The table is expanded to Q sub-rows per sample (``m_s + (q / Q) s_s``, a per-pose
  lerp of S Q rows, written out once: fused into the gathers every read redid the lerp) and
  pass 2 is the LBS kernel with the pose-independent index ``round(u Q)``: one table read per
  coefficient and influence, as LBS.  It equals the reference at ``u`` rounded to ``1/Q`` of a
  sample step, a different approximation: against exact skinning mean 0.063 % / max 1.90 % of
  the limb radius for Q = 16, against 0.032 % / 1.75 % (Q = 64: 0.039 % / 1.61 %, but its
  147 KB table per pose leaves L1/L2: 0.62x).  Q = 16, chunks of 8, CPU time: 0.81-0.87x LBS
  (0.45-0.50x without sub-rows, same runs); ``skinning_bench`` wall, four runs: 0.83-1.05x.
  With both styles (the style rotation read from sub-rows too): 58.9 against 73.8 ms, 0.30x
  against 0.24x LBS: the style offsets (about 19 ms) and the final renormalization (about 7 ms)
  stay.
* Kept (session 10, second half): the style offset folded into the blend loops
  (:func:`blend_skin_styled`).  A small pass (:func:`style_scalars`) writes ``w (D(v') - v')``
  in the rotation's first two columns for positions and normals as one (4, V) array per pose;
  the blend loops add ``R_d (d_x, d_y, 0)`` with the dominant spline's rotation gathered as one
  more influence (6 sub-row values, or 6 rows and 6 slopes without sub-rows), so no (V, 3)
  offsets are written and re-read and the add pass goes.  The styled normal is the raw blend
  plus the offset, normalized once: this is Eq. 5.13 (``skin_exact`` normalizes
  ``Σ w_i R_i n'_i`` with the styled ``n'_d``), where the separate path normalized the blend,
  added the offset and normalized again (max normal error against exact, 8 limb poses:
  0.092 -> 0.0078 with 16 sub-rows, 0.092 -> 0.0052 without; positions unchanged to 1e-6).
  80 poses x 12,546 vertices, chunks of 8, CPU time, best of 9 (7) interleaved rounds, load
  3.0-3.3: 16 sub-rows + both styles 43.8 -> 34.5 ms, 0.42 -> 0.53x the chunked LBS (18.4 ms);
  without sub-rows 79.9 -> 70.6 ms (0.28 -> 0.31x, LBS 22.3 ms, load from a test run alongside).
  ``skinning_bench`` (wall, best of 9, load 3.1-3.3): 16 sub-rows + both styles 0.56x (1
  device) and 0.58x (2 devices) the chunked LBS, without sub-rows 0.33x / 0.34x; vmapped over
  all 80 poses at once the sub-row tables leave the cache: 0.39x (0.42x without sub-rows).
* Fitting (``fit_style(samples=S)``) gains where inference cannot: the poses are fixed, so pass 1
  and the unstyled blend are computed once per fit and a step differentiates only the style
  offsets: 186 -> 480 and 245 -> 807 steps/s (``experiments/fit_style.py``, 1,536 vertices).
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
        is faster than stacking (3, V) and transposing, 47 against 66 ms for 80 x 12,546).
    """
    m = _coefficients(columns, index, weight, frac)
    px, py, pz = _linear(m, vertices)
    pos = jnp.stack([px + m[9], py + m[10], pz + m[11]], axis=-1)
    # fresh gathers for the normals: one consumer per gather, so each set fuses into one loop
    index, weight, frac = lax.optimization_barrier((index, weight, frac))
    raw = jnp.stack(_linear(_coefficients(columns, index, weight, frac), normals), axis=-1)
    # Normalize in a second pass over the written (V, 3) normals.  Fused into the gather loop,
    # every output component would recompute all three components for the length (3x the
    # normal's gathers): 52 -> 30 ms CPU time for 80 poses x 12,546 vertices, 64 bones, I = 4.
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
    # gathers (4 to 6 times): 88 -> 57 ms CPU time for 80 poses x 12,546 vertices, both
    # envelopes (the vmapped reference: 107-113 ms).
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
