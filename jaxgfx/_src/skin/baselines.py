"""Baselines driven by the same skeleton: linear blend and dual quaternion skinning (thesis 5.9).

The thesis compares spline skinning with matrix skinning (SSD / linear blend skinning) and dual
quaternion skinning (Kavan et al. 2007).  :func:`bone_transforms` turns a spline pose into two
rigid bones per spline, so both baselines see exactly the joint rotations and twist the spline
sees; :func:`bone_weights_from_binding` derives their influences from a spline binding.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxgfx._src.checks import (
    check_finite,
    checking,
    require_finite,
    require_indices,
    require_values,
)
from jaxgfx._src.eager import compiled_when_eager
from jaxgfx._src.frames import per_frame, split_rows
from jaxgfx._src.skin.binding import SkinBinding
from jaxgfx._src.skin.geometry import _EPS_SQ, _compose, _concrete, _normalize, _safe_norm
from jaxgfx._src.skin.kernels import blend_skin, normalize_rows
from jaxgfx._src.skin.rig import SplinePose, SplineRig
from jaxgfx._src.skin.spline import frame_inverse, spline_frames

__all__ = [
    "bone_transforms",
    "bone_weights_from_binding",
    "lbs_vertex",
    "linear_blend_skinning",
    "matrix_to_quaternion",
    "dual_quaternions",
    "dqs_vertex",
    "dual_quaternion_skinning",
    "POSE_CHUNK",
]


# ----------------------------------------------------------------------------------------------
# the skeleton as bones
# ----------------------------------------------------------------------------------------------


def bone_transforms(rig: SplineRig, pose: SplinePose) -> jax.Array:
    """Rigid bone transforms of the same skeleton: two bones per spline.

    Bone ``2k`` is the spline frame change at ``x = 0`` and bone ``2k + 1`` at ``x = 1``,
    ``B(x) B'(x)^{-1}``, so LBS/DQS see exactly the joint rotations and twist the spline sees.

    Returns:
        (2K, 3, 4) affine transforms ``[R | t]`` with proper rotations.
    """
    ends = jnp.array([0.0, 1.0])
    posed = spline_frames(rig, pose, ends)
    bound = spline_frames(rig, rig.bind, ends)
    rel = jax.vmap(jax.vmap(lambda p, b: _compose(p, frame_inverse(b))))(posed, bound)
    return rel.reshape(-1, 3, 4)


def bone_weights_from_binding(binding: SkinBinding, blend_width: float = 0.25):
    """LBS influences equal to a spline binding: each spline weight split between its two bones.

    The split is a smoothstep in ``x`` of width ``blend_width`` centred at ``x = 0.5`` (the joint).

    Returns:
        joints (V, 2I) int32 and weights (V, 2I) float32 summing to one.
    """
    if not blend_width > 0:
        raise ValueError(f"blend_width must be > 0, got {blend_width}")
    t = jnp.clip((binding.x - 0.5) / blend_width + 0.5, 0.0, 1.0)
    s = t * t * (3 - 2 * t)
    joints = jnp.concatenate([2 * binding.spline, 2 * binding.spline + 1], axis=1)
    weights = jnp.concatenate([binding.weight * (1 - s), binding.weight * s], axis=1)
    return joints.astype(jnp.int32), weights


# ----------------------------------------------------------------------------------------------
# linear blend skinning (SSD)
# ----------------------------------------------------------------------------------------------


def lbs_vertex(
    transforms: jax.Array, joints: jax.Array, weights: jax.Array, vertex: jax.Array, normal
) -> tuple[jax.Array, jax.Array]:
    """Linear blend skinning (SSD) of one vertex: ``(Σ w_j M_j) v``.

    Args:
        transforms: (J, 3, 4) bone transforms (pose · inverse bind).
        joints: (I,) bone indices.
        weights: (I,) weights summing to one.
        vertex: (3,) bind position.
        normal: (3,) bind normal.

    Returns:
        Position (3,) and unit normal (3,).
    """
    # blend first, then one affine map; columns of [R | t] contiguous, as in the sampled spline path
    table = jnp.swapaxes(transforms, -1, -2).reshape(-1, 12)
    m = jnp.dot(weights, table[joints])
    pos = m[0:3] * vertex[0] + m[3:6] * vertex[1] + m[6:9] * vertex[2] + m[9:12]
    nrm = m[0:3] * normal[0] + m[3:6] * normal[1] + m[6:9] * normal[2]
    return pos, nrm * lax.rsqrt(jnp.maximum(jnp.sum(nrm * nrm), _EPS_SQ))


def _check_lbs_inputs(transforms, vertices, normals, joints, weights, where: str):
    """Shapes always; values where concrete, and traced ones inside :func:`~jaxgfx.checks.checked`.

    A NaN transform or weight spreads to every vertex it moves, and an out-of-range joint
    is clamped to the last bone by the gathers: wrong positions, no error.
    """
    nj = jnp.shape(transforms)[0]
    if jnp.shape(transforms)[1:] != (3, 4) and jnp.shape(transforms)[1:] != (4, 4):
        raise ValueError(f"transforms must have shape (J, 3, 4), got {jnp.shape(transforms)}")
    nv = jnp.shape(vertices)[0]
    if jnp.shape(joints)[0] != nv or jnp.shape(weights) != jnp.shape(joints):
        raise ValueError(
            f"joints {jnp.shape(joints)} and weights {jnp.shape(weights)} must both be (V, I) "
            f"with V = {nv} (vertices)"
        )
    j = _concrete(joints)
    if j is not None and j.size and (j.min() < 0 or j.max() >= nj):
        raise ValueError(f"joints out of range [0, {nj})")
    arrays = {"transforms": transforms, "vertices": vertices, "normals": normals}
    for name, a in {**arrays, "weights": weights}.items():
        c = _concrete(a)
        if c is not None:
            check_finite(name, c)
    w = _concrete(weights)
    if w is not None and (np.any(w < 0) or np.any(np.abs(w.sum(-1) - 1) > 1e-3)):
        raise ValueError("weights must be non-negative and sum to one per vertex")
    for name, a in arrays.items():
        require_finite(name, a, where)
    require_indices("joints", joints, nj, "bones (transforms)", where)
    require_finite("weights", weights, where)
    if checking():
        wj = jnp.asarray(weights)
        total = jnp.sum(wj, axis=-1)
        ok = jnp.all(wj >= 0, axis=-1) & (jnp.abs(total - 1) <= 1e-3)
        rule = "a vertex's weights sum to {} (must be >= 0 and sum to one)"
        require_values("weights", ok, total, rule, where)


def linear_blend_skinning(transforms, vertices, normals, joints, weights):
    """LBS of a mesh; returns positions (V, 3) and unit normals (V, 3).

    Equals :func:`lbs_vertex` vmapped over the vertices (to float32 rounding) but runs the
    structure-of-arrays kernel that XLA:CPU fuses over the vertices.  Work follows the data:
    with the per-vertex arrays (``vertices``, ``normals``, ``joints``, ``weights``) sharded
    along V over a mesh, each device skins its own vertices; under ``jax.vmap`` over poses a
    batch sharded over a mesh is split the same way, and on a CPU each device runs its poses
    in small chunks (the chunk's outputs stay in cache).

    Args:
        transforms: (J, 3, 4) (or (J, 4, 4)) bone matrices, bind space to posed.
        vertices: (V, 3) bind positions.
        normals: (V, 3) bind normals.
        joints: (V, I) int bone indices.
        weights: (V, I) weights, non-negative, summing to one per vertex.

    Returns:
        Positions (V, 3) and unit normals (V, 3), differentiable in every float input
        (``jax.grad``, also under ``vmap``: the derivatives of :func:`lbs_vertex`).

    Raises:
        ValueError: bad shapes; non-finite arrays, joints out of range or weights that are
            negative or do not sum to one, where concrete (eager calls) and, for traced
            arrays, inside :func:`~jaxgfx.checks.checked`.
    """
    _check_lbs_inputs(transforms, vertices, normals, joints, weights, "linear_blend_skinning")
    return _LBS(transforms, vertices, normals, joints, weights)


POSE_CHUNK = 8
"""Poses per step of the CPU batching rule of the mesh kernels."""


def _float_type(*arrays):
    """The floating type the mesh kernels compute in: the inputs', at least float32."""
    return jnp.result_type(*arrays, jnp.float32)


def _lbs_mesh(transforms, vertices, normals, joints, weights):
    dt = _float_type(transforms, vertices, normals, weights)
    t = jnp.asarray(transforms, dt)[:, :3, :]
    columns = jnp.swapaxes(t, -1, -2).reshape(-1, 12).T  # (12, J), columns of [R | t]
    return blend_skin(
        columns,
        jnp.asarray(joints).astype(jnp.int32).T,
        jnp.asarray(weights, dt).T,
        None,
        jnp.asarray(vertices, dt).T,
        jnp.asarray(normals, dt).T,
    )


def _differentiable(kernel):
    """``kernel`` with the CPU's batching rule of :data:`POSE_CHUNK` poses a step under
    ``vmap``, and the derivatives of the plain ``kernel``.

    The batching rule (a ``custom_vmap``) has no reverse mode of its own: ``jax.grad`` through
    it fails ("Linearization failed").  Its JVP is the plain kernel's, which batches as
    ``vmap`` does and is linear in the tangents, so reverse mode transposes it.
    """
    batched = per_frame(kernel, chunk=POSE_CHUNK)

    @jax.custom_jvp
    def fn(transforms, vertices, normals, joints, weights):
        return batched(transforms, vertices, normals, joints, weights)

    @fn.defjvp
    def fn_jvp(primals, tangents):
        return jax.jvp(kernel, primals, tangents)

    return fn


_LBS = compiled_when_eager(split_rows(_differentiable(_lbs_mesh), rows=(1, 2, 3, 4)))


# ----------------------------------------------------------------------------------------------
# dual quaternion skinning (Kavan et al. 2007)
# ----------------------------------------------------------------------------------------------


def matrix_to_quaternion(rot: jax.Array) -> jax.Array:
    """Unit quaternion ``(w, x, y, z)`` of a rotation matrix (3, 3) (Shepperd's method)."""
    m = rot
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    cands = jnp.stack(
        [
            jnp.stack([1 + tr, m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]),
            jnp.stack(
                [
                    m[2, 1] - m[1, 2],
                    1 + m[0, 0] - m[1, 1] - m[2, 2],
                    m[0, 1] + m[1, 0],
                    m[0, 2] + m[2, 0],
                ]
            ),
            jnp.stack(
                [
                    m[0, 2] - m[2, 0],
                    m[0, 1] + m[1, 0],
                    1 - m[0, 0] + m[1, 1] - m[2, 2],
                    m[1, 2] + m[2, 1],
                ]
            ),
            jnp.stack(
                [
                    m[1, 0] - m[0, 1],
                    m[0, 2] + m[2, 0],
                    m[1, 2] + m[2, 1],
                    1 - m[0, 0] - m[1, 1] + m[2, 2],
                ]
            ),
        ]
    )
    # pick the numerically largest candidate; each is 4 q_i q (up to sign)
    diag = jnp.stack([tr, m[0, 0], m[1, 1], m[2, 2]])
    q = cands[jnp.argmax(diag)]
    q = q / _safe_norm(q).clip(1e-12)
    return jnp.where(q[0] < 0, -q, q)


def _qmul(a: jax.Array, b: jax.Array) -> jax.Array:
    w1, x1, y1, z1 = a[0], a[1], a[2], a[3]
    w2, x2, y2, z2 = b[0], b[1], b[2], b[3]
    return jnp.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def dual_quaternions(transforms: jax.Array) -> jax.Array:
    """Unit dual quaternions (J, 8) ``[q_r | q_d]`` of rigid transforms (J, 3, 4)."""

    def one(t):
        qr = matrix_to_quaternion(t[:, :3])
        qd = 0.5 * _qmul(jnp.concatenate([jnp.zeros(1), t[:, 3]]), qr)
        return jnp.concatenate([qr, qd])

    return jax.vmap(one)(transforms)


def dqs_vertex(
    dual: jax.Array, joints: jax.Array, weights: jax.Array, vertex: jax.Array, normal: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Dual quaternion skinning of one vertex (Kavan et al. 2007).

    Quaternions are sign-aligned to the dominant influence before blending (shortest path).

    Args:
        dual: (J, 8) unit dual quaternions.
        joints, weights: (I,) influences.
        vertex, normal: (3,) bind position and normal.

    Returns:
        Position (3,) and unit normal (3,).
    """
    dq = dual[joints]
    pivot = dq[jnp.argmax(weights), :4]
    signs = jnp.where(dq[:, :4] @ pivot < 0, -1.0, 1.0)
    b = jnp.dot(weights * signs, dq)
    length = _safe_norm(b[:4])
    safe = jnp.where(length > 0, length, 1.0)
    qr = b[:4] / safe
    qd = b[4:] / safe
    w, v = qr[0], qr[1:]

    def rotate(p):
        return p + 2 * jnp.cross(v, jnp.cross(v, p) + w * p)

    # translation = vector part of 2 q_d conj(q_r)
    trans = 2 * (w * qd[1:] - qd[0] * v + jnp.cross(v, qd[1:]))
    return rotate(vertex) + trans, _normalize(rotate(normal), jnp.array([0.0, 1.0, 0.0]))


def dual_quaternion_skinning(transforms, vertices, normals, joints, weights):
    """DQS of a mesh; returns positions (V, 3) and unit normals (V, 3).

    Equals :func:`dqs_vertex` vmapped over the vertices (to float32 rounding) in the
    structure-of-arrays layout of :func:`linear_blend_skinning`: the 8 dual-quaternion
    coefficients of each influence are scalar gathers of (V,) index arrays, blended with the
    signs that align each quaternion to the dominant influence's, then applied to x, y, z.
    Placement and batching as :func:`linear_blend_skinning`.

    Args:
        transforms, vertices, normals, joints, weights: as :func:`linear_blend_skinning`;
            the transforms must be rigid.

    Raises:
        ValueError: as :func:`linear_blend_skinning`.
    """
    _check_lbs_inputs(transforms, vertices, normals, joints, weights, "dual_quaternion_skinning")
    return _DQS(transforms, vertices, normals, joints, weights)


def _dqs_mesh(transforms, vertices, normals, joints, weights):
    dt = _float_type(transforms, vertices, normals, weights)
    dual = dual_quaternions(jnp.asarray(transforms, dt)[:, :3, :])  # (J, 8)
    columns = dual.T  # (8, J)
    index = jnp.asarray(joints).astype(jnp.int32).T  # (I, V)
    weight = jnp.asarray(weights, dt).T
    joints_n = columns.shape[1]
    # Every quaternion is flipped into the dominant influence's hemisphere.  The sign depends
    # only on the pair of bones, so it is one lookup in a (J, J) table per influence; the
    # signed weights are written out first, so each coefficient gather below has a single
    # consumer and XLA:CPU fuses the blend into one loop (a gather read twice is written out).
    rot = columns[:4].T  # (J, 4)
    sign_table = jnp.where(rot @ rot.T < 0, -1.0, 1.0).reshape(-1)  # (J * J,)
    dom = jnp.argmax(weight, axis=0)
    pivot = jnp.take_along_axis(index, dom[None], axis=0)[0]
    signed = lax.optimization_barrier(weight * sign_table[pivot * joints_n + index])
    blend = [sum(signed[i] * columns[c][index[i]] for i in range(index.shape[0])) for c in range(8)]
    # Written out once: positions and normals both read the blend.  The gathers fuse into
    # the loop that writes it; as (8, V) rows it runs faster than as (V, 8) (design notes).
    table = lax.optimization_barrier(jnp.stack(blend, axis=0))  # (8, V)
    q = [table[c] for c in range(8)]
    length = jnp.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    inv = 1.0 / jnp.where(length > 0, length, 1.0)
    w0, vx, vy, vz = (q[c] * inv for c in range(4))
    d0, dx, dy, dz = (q[c] * inv for c in range(4, 8))

    def rotate(px, py, pz):  # p + 2 v x (v x p + w p)
        cx = vy * pz - vz * py + w0 * px
        cy = vz * px - vx * pz + w0 * py
        cz = vx * py - vy * px + w0 * pz
        return (
            px + 2 * (vy * cz - vz * cy),
            py + 2 * (vz * cx - vx * cz),
            pz + 2 * (vx * cy - vy * cx),
        )

    # translation: vector part of 2 q_d conj(q_r)
    tx = 2 * (w0 * dx - d0 * vx + (vy * dz - vz * dy))
    ty = 2 * (w0 * dy - d0 * vy + (vz * dx - vx * dz))
    tz = 2 * (w0 * dz - d0 * vz + (vx * dy - vy * dx))
    v = jnp.asarray(vertices, dt).T
    n = jnp.asarray(normals, dt).T
    px, py, pz = rotate(v[0], v[1], v[2])
    pos = jnp.stack([px + tx, py + ty, pz + tz], axis=-1)
    raw = jnp.stack(rotate(n[0], n[1], n[2]), axis=-1)
    return pos, normalize_rows(lax.optimization_barrier(raw))


_DQS = compiled_when_eager(split_rows(_differentiable(_dqs_mesh), rows=(1, 2, 3, 4)))
