"""Spline skinning and deformation styles (thesis chapter 5).

The pieces follow the thesis, one function per step, each written for one item (one spline, one
vertex) and batched with :func:`jax.vmap` by the caller:

* Splines (Eq. 5.1-5.3): :func:`bezier_point`, :func:`spline_point`, :func:`spline_tangent`.
* Frames (Eq. 5.4): :func:`spline_frame` gives ``B = [b_N | b_B | b_T | b_O]`` as a (3, 4) matrix.
* Binding (Eq. 5.5-5.6): :func:`bind_vertex` / :func:`bind_mesh`.
* Spline skinning (Eq. 5.7): :func:`skin_vertex_exact` (frames per vertex) and the thesis's fast
  path, :func:`sample_spline_frames` (pass 1) + :func:`skin_vertex_sampled` (pass 2).
* Deformation styles (Eq. 5.8-5.13): :class:`Style`, :func:`radial_scale`, :func:`rect_scale`,
  :func:`apply_style`.
* Baselines driven by the same skeleton: :func:`bone_transforms`, :func:`lbs_vertex` (linear blend
  skinning / SSD) and :func:`dqs_vertex` (dual quaternion skinning, Kavan et al.).

Conventions and the choices the thesis leaves open:

* **Frame normal.** The thesis's normal ``b_N = Δ12 × Δ23`` vanishes for a straight spline (the
  usual rest pose) and flips sign when a bend passes through straight. jaxgfx instead carries a
  per-spline *reference normal* ``r`` (given at bind time, perpendicular to ``Δ12``).  In a pose,
  ``r`` is moved to the posed first segment by the minimal rotation ``bind Δ12 → posed Δ12`` and
  then transported along the curve by the minimal rotation ``b_T(0) → b_T(x)`` (for the planar
  curve this is the rotation-minimizing frame).  When ``r`` is the hinge axis and the spline
  bends about it in the positive sense, this equals the thesis's normalized ``Δ12 × Δ23``; it
  is finite, continuous and differentiable at the straight pose.
* **Twist.** ``γ`` (radians) rotates the frame about ``b_T`` by ``γ·x``: no twist at ``x = 0``,
  the full twist at ``x = 1``, which is what spreads a 180° twist along the limb.
* **Handedness.** ``[b_N | b_B | b_T]`` with ``b_B = b_N × b_T`` is left-handed (det -1), exactly as
  in Eq. 5.4; only ``B · B'^{-1}`` (a proper rotation) acts on vertices, so this is harmless.
* **Pose weights of the styles.** ``β = ∠(Δ12, Δ23) ∈ [0, π]`` enters the weights as ``β/π`` and
  the twist as ``|γ|/π``, so ``w_f, w_l ∈ [0, 1]`` always and ``w_r ∈ [0, 1]`` for twists up to 180°
  (larger sums are normalized by Eq. 5.9's ``max(1, w_sum)``).
* **Radial scaling** scales only the cross-section coordinates ``(v'_x, v'_y)`` of ``v'``; the
  binding puts bound vertices on the plane ``v'_z = 0`` (Eq. 5.5), so this equals Eq. 5.8 there and
  keeps vertices beyond the spline ends from being stretched along the tangent.
* **Weights** must be non-negative and sum to one per vertex (Eq. 5.7); they are checked, not
  renormalized.
* **Fast path layout.** Pass 1 folds the bind frames into ``B'' = B B'^{-1}`` per sample (Eq. 5.7
  says it may be precomputed) and stores each sample with its slope to the next one, and the
  binding folds spline index and ``x`` into one coordinate ``u``; pass 2 then reads per influence
  exactly what matrix skinning reads (one index-like value, one weight) plus one table row.  The
  style on the dominant spline (thesis 5.8.2) is added as ``w_d R_d (D(v'_d) - v'_d)``, which equals
  Eq. 5.13 with the style on that spline only.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

__all__ = [
    "SplineRig",
    "SplinePose",
    "SkinBinding",
    "Style",
    "make_rig",
    "bind_pose",
    "validate_pose",
    "bezier_point",
    "bezier_tangent",
    "spline_point",
    "spline_tangent",
    "bend_angle",
    "start_normal",
    "spline_frame",
    "spline_frames",
    "frame_inverse",
    "attach_children",
    "forward_kinematics",
    "axis_angle_to_matrix",
    "bind_vertex",
    "bind_mesh",
    "brute_force_binding",
    "identity_style",
    "make_style",
    "sample_texture",
    "sample_curve",
    "radial_scale",
    "rect_scale",
    "apply_style",
    "skin_vertex_exact",
    "skin_exact",
    "sample_spline_frames",
    "SampledBinding",
    "prepare_sampled",
    "skin_vertex_sampled",
    "style_offset_sampled",
    "skin_sampled",
    "bone_transforms",
    "bone_weights_from_binding",
    "lbs_vertex",
    "linear_blend_skinning",
    "matrix_to_quaternion",
    "dual_quaternions",
    "dqs_vertex",
    "dual_quaternion_skinning",
    "limb_mesh",
    "muscle_style",
    "demo_character",
]

# Squared lengths below this count as zero (float32: lengths ~1e-6 of a unit-sized rig).
_EPS_SQ = 1e-12
# Texture row 0 is α = 0 (the b_B side), the last row α = π.
_MAX_INFLUENCES = 3


# ----------------------------------------------------------------------------------------------
# small numerically safe helpers (double-where trick)
# ----------------------------------------------------------------------------------------------


def _safe_norm(v: jax.Array) -> jax.Array:
    """Euclidean norm over the last axis with a finite (zero) gradient at the origin."""
    sq = jnp.sum(v * v, axis=-1)
    ok = sq > _EPS_SQ
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)


def _normalize(v: jax.Array, fallback: jax.Array) -> jax.Array:
    """``v / |v|``, or ``fallback`` where ``v`` is (numerically) zero; gradients stay finite."""
    sq = jnp.sum(v * v, axis=-1, keepdims=True)
    ok = sq > _EPS_SQ
    return jnp.where(ok, v * lax.rsqrt(jnp.where(ok, sq, 1.0)), fallback)


def _pow01(base: jax.Array, exponent: jax.Array) -> jax.Array:
    """``base ** exponent`` for ``base >= 0`` whose gradient w.r.t. the exponent is finite at 0."""
    pos = base > 0
    return jnp.where(pos, jnp.where(pos, base, 1.0) ** exponent, 0.0)


def _any_perpendicular(d: jax.Array) -> jax.Array:
    """A unit vector perpendicular to unit ``d`` (used only as a finite fallback)."""
    axis = jnp.where(jnp.abs(d[0]) < 0.9, jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0]))
    return _normalize(jnp.cross(d, axis), jnp.array([0.0, 0.0, 1.0]))


def _rotate_minimal(a: jax.Array, b: jax.Array, v: jax.Array) -> jax.Array:
    """Apply the minimal rotation taking unit ``a`` to unit ``b`` to ``v``.

    ``R = I + [w]_x + [w]_x^2 / (1 + a·b)`` with ``w = a × b`` needs no normalization of the axis,
    so it is smooth at ``a = b`` (where ``R = I``).  Exactly opposite directions have no unique
    minimal rotation; there ``v`` is reflected through the plane normal to ``a`` (finite output).
    """
    w = jnp.cross(a, b)
    c = jnp.dot(a, b)
    ok = c > -1.0 + 1e-6
    denom = jnp.where(ok, 1.0 + c, 1.0)
    wv = jnp.cross(w, v)
    rotated = v + wv + jnp.cross(w, wv) / denom
    return jnp.where(ok, rotated, v - 2.0 * jnp.dot(a, v) * a)


def _concrete(x) -> np.ndarray | None:
    """NumPy view of ``x`` if it is concrete (not a tracer), else ``None``."""
    if isinstance(x, jax.core.Tracer):
        return None
    return np.asarray(x)


# ----------------------------------------------------------------------------------------------
# pytrees
# ----------------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SplinePose:
    """Pose of K splines (thesis 5.4).

    Attributes:
        points: (K, 3, 3) control points ``p1, p2, p3`` of each spline.
        stiffness: (K,) exponent ``a >= 2`` of the modified Bézier (Eq. 5.3).
        twist: (K,) twist ``γ`` in radians, reached at ``x = 1``.
    """

    points: jax.Array
    stiffness: jax.Array
    twist: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SplineRig:
    """Splines in their bind pose, their reference normals and their hierarchy (Fig. 5.16).

    Attributes:
        bind: the bind pose ``B'`` (Eq. 5.7).
        reference_normal: (K, 3) unit normal ``b_N`` at ``x = 0`` in the bind pose, perpendicular to
            the first segment ``Δ12``.
        parent: static tuple of K ints, the parent spline of each spline or -1; parents come first.
        parent_point: static tuple of K ints in {0, 1, 2}: the parent's control point that this
            spline's ``p1`` is attached to (ignored for roots).
    """

    bind: SplinePose
    reference_normal: jax.Array
    parent: tuple[int, ...] = dataclasses.field(metadata=dict(static=True), default=())
    parent_point: tuple[int, ...] = dataclasses.field(metadata=dict(static=True), default=())

    @property
    def num_splines(self) -> int:
        """Number of splines K."""
        return len(self.parent)


class SkinBinding(NamedTuple):
    """Per-vertex binding to up to three splines (Eq. 5.5-5.7), I = influences per vertex."""

    spline: jax.Array  # shape=(V, I), dtype=int32, spline index of each influence
    weight: jax.Array  # shape=(V, I), dtype=float32, skinning weights w_i, rows sum to 1
    x: jax.Array  # shape=(V, I), dtype=float32, spline parameter of the foot point (Eq. 5.5)
    local: jax.Array  # shape=(V, I, 3), dtype=float32, v' = B'^{-1} v (Eq. 5.6)
    local_normal: jax.Array  # shape=(V, I, 3), dtype=float32, normal in bind spline space
    rest: jax.Array  # shape=(V, 3), dtype=float32, bind-pose vertex v
    rest_normal: jax.Array  # shape=(V, 3), dtype=float32, bind-pose unit normal


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


def _check_points(points: np.ndarray, name: str) -> None:
    if points.ndim != 3 or points.shape[1:] != (3, 3):
        raise ValueError(f"{name} must have shape (K, 3, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name} must be finite (found NaN or inf)")


def _check_stiffness(stiffness: np.ndarray, k: int, name: str) -> None:
    if stiffness.shape != (k,):
        raise ValueError(f"{name} must have shape ({k},), got {stiffness.shape}")
    if not np.all(np.isfinite(stiffness)) or np.any(stiffness < 2.0):
        raise ValueError(f"{name} must be finite and >= 2 (Eq. 5.3), got {stiffness}")


def validate_pose(rig: SplineRig, pose: SplinePose) -> None:
    """Raise ``ValueError`` naming the field if a concrete pose is malformed.

    Traced poses (inside ``jit``) are only shape-checked.
    """
    k = rig.num_splines
    if tuple(jnp.shape(pose.points)) != (k, 3, 3):
        raise ValueError(f"pose.points must have shape ({k}, 3, 3), got {jnp.shape(pose.points)}")
    for name in ("stiffness", "twist"):
        if tuple(jnp.shape(getattr(pose, name))) != (k,):
            raise ValueError(f"pose.{name} must have shape ({k},)")
    pts = _concrete(pose.points)
    if pts is not None:
        _check_points(pts, "pose.points")
    a = _concrete(pose.stiffness)
    if a is not None:
        _check_stiffness(a, k, "pose.stiffness")
    tw = _concrete(pose.twist)
    if tw is not None and not np.all(np.isfinite(tw)):
        raise ValueError("pose.twist must be finite")


def make_rig(
    control_points,
    *,
    stiffness=None,
    twist=None,
    reference_normal=None,
    parent: Sequence[int] | None = None,
    parent_point: Sequence[int] | None = None,
) -> SplineRig:
    """Build a :class:`SplineRig` from bind-pose control points, checking every argument.

    Args:
        control_points: (K, 3, 3) bind-pose control points; both segments must have length > 0.
        stiffness: (K,) or scalar ``a >= 2`` (default 4).
        twist: (K,) bind twist in radians (default 0).
        reference_normal: (K, 3) bind normals; each is projected onto the plane normal to
            ``Δ12`` and normalized (it must not be parallel to ``Δ12``).  Default: the thesis's
            ``Δ12 × Δ23`` where the spline is bent, else any vector perpendicular to ``Δ12``.
        parent: K ints, parent spline or -1, each parent index smaller than the child's.
        parent_point: K ints in {0, 1, 2} (control point of the parent the child hangs from).

    Returns:
        The rig; arrays float32.
    """
    pts = np.asarray(control_points, dtype=np.float64)
    _check_points(pts, "control_points")
    k = pts.shape[0]
    if k < 1:
        raise ValueError("control_points must hold at least one spline")
    a = np.full(k, 4.0) if stiffness is None else np.broadcast_to(np.asarray(stiffness, float), k)
    _check_stiffness(np.asarray(a), k, "stiffness")
    tw = np.zeros(k) if twist is None else np.broadcast_to(np.asarray(twist, float), (k,))
    if not np.all(np.isfinite(tw)):
        raise ValueError("twist must be finite")
    d12 = pts[:, 1] - pts[:, 0]
    d23 = pts[:, 2] - pts[:, 1]
    l12 = np.linalg.norm(d12, axis=-1)
    l23 = np.linalg.norm(d23, axis=-1)
    if np.any(l12 < 1e-6) or np.any(l23 < 1e-6):
        raise ValueError("control_points: every spline needs p1 != p2 and p2 != p3")
    t0 = d12 / l12[:, None]
    if reference_normal is None:
        ref = np.cross(d12, d23)
        for i in range(k):
            if np.linalg.norm(ref[i]) < 1e-6 * l12[i] * l23[i]:
                helper = np.eye(3)[int(np.argmin(np.abs(t0[i])))]
                ref[i] = np.cross(t0[i], helper)
    else:
        ref = np.asarray(reference_normal, dtype=np.float64)
        if ref.shape != (k, 3) or not np.all(np.isfinite(ref)):
            raise ValueError(f"reference_normal must be a finite ({k}, 3) array, got {ref.shape}")
    ref = ref - np.sum(ref * t0, axis=-1, keepdims=True) * t0
    norms = np.linalg.norm(ref, axis=-1)
    if np.any(norms < 1e-6):
        raise ValueError("reference_normal must not be parallel to the first segment p2 - p1")
    ref = ref / norms[:, None]
    par = tuple(-1 for _ in range(k)) if parent is None else tuple(int(p) for p in parent)
    ppt = (2,) * k if parent_point is None else tuple(int(p) for p in parent_point)
    if len(par) != k or len(ppt) != k:
        raise ValueError(f"parent and parent_point must have {k} entries")
    for i, (p, j) in enumerate(zip(par, ppt, strict=True)):
        if p != -1 and not 0 <= p < i:
            raise ValueError(f"parent[{i}] = {p}: must be -1 or an earlier spline index")
        if j not in (0, 1, 2):
            raise ValueError(f"parent_point[{i}] = {j}: must be 0, 1 or 2")
    bind = SplinePose(
        points=jnp.asarray(pts, jnp.float32),
        stiffness=jnp.asarray(a, jnp.float32),
        twist=jnp.asarray(tw, jnp.float32),
    )
    return SplineRig(
        bind=bind,
        reference_normal=jnp.asarray(ref, jnp.float32),
        parent=par,
        parent_point=ppt,
    )


def bind_pose(rig: SplineRig) -> SplinePose:
    """The rig's bind pose (a convenient starting pose)."""
    return rig.bind


# ----------------------------------------------------------------------------------------------
# splines and frames (Eq. 5.1-5.4)
# ----------------------------------------------------------------------------------------------


def bezier_point(points: jax.Array, x: jax.Array) -> jax.Array:
    """Quadratic Bézier ``f_b(x)`` (Eq. 5.2) of control points (3, 3); returns (3,)."""
    return (1 - x) ** 2 * points[0] + 2 * x * (1 - x) * points[1] + x**2 * points[2]


def bezier_tangent(points: jax.Array, x: jax.Array) -> jax.Array:
    """Derivative ``f'_b(x)`` (Eq. 5.2); returns (3,)."""
    return 2 * (x - 1) * points[0] + (2 - 4 * x) * points[1] + 2 * x * points[2]


def spline_point(points: jax.Array, stiffness: jax.Array, x: jax.Array) -> jax.Array:
    """Modified Bézier ``f_m(x) = p1 + (1-(1-x)^a) Δ12 + x^a Δ23`` (Eq. 5.3).

    Args:
        points: (3, 3) control points.
        stiffness: () exponent ``a >= 2``; ``a = 2`` is the quadratic Bézier.
        x: () spline parameter in [0, 1].

    Returns:
        (3,) point on the spline.
    """
    d12 = points[1] - points[0]
    d23 = points[2] - points[1]
    return points[0] + (1 - _pow01(1 - x, stiffness)) * d12 + _pow01(x, stiffness) * d23


def spline_tangent(points: jax.Array, stiffness: jax.Array, x: jax.Array) -> jax.Array:
    """Derivative ``f'_m(x) = a (1-x)^{a-1} Δ12 + a x^{a-1} Δ23`` (Eq. 5.3); returns (3,)."""
    d12 = points[1] - points[0]
    d23 = points[2] - points[1]
    a = stiffness
    return a * _pow01(1 - x, a - 1) * d12 + a * _pow01(x, a - 1) * d23


def bend_angle(points: jax.Array) -> jax.Array:
    """Bend angle ``β = ∠(Δ12, Δ23)`` in [0, π] (thesis 5.6.1), finite gradient when straight."""
    d12 = points[1] - points[0]
    d23 = points[2] - points[1]
    return jnp.arctan2(_safe_norm(jnp.cross(d12, d23)), jnp.dot(d12, d23))


def start_normal(
    bind_points: jax.Array, reference_normal: jax.Array, points: jax.Array
) -> jax.Array:
    """Posed normal at ``x = 0``: the bind reference normal moved with the first segment.

    Args:
        bind_points: (3, 3) bind control points.
        reference_normal: (3,) unit bind normal, perpendicular to the bind ``Δ12``.
        points: (3, 3) posed control points.

    Returns:
        (3,) unit normal perpendicular to the posed ``Δ12``.
    """
    fallback = jnp.array([1.0, 0.0, 0.0])
    t_bind = _normalize(bind_points[1] - bind_points[0], fallback)
    t_pose = _normalize(points[1] - points[0], t_bind)
    n = _rotate_minimal(t_bind, t_pose, reference_normal)
    n = n - jnp.dot(n, t_pose) * t_pose
    return _normalize(n, _any_perpendicular(t_pose))


def spline_frame(
    points: jax.Array,
    stiffness: jax.Array,
    twist: jax.Array,
    normal0: jax.Array,
    x: jax.Array,
) -> jax.Array:
    """Spline frame ``B(x) = [b_N | b_B | b_T | b_O]`` (Eq. 5.4) as a (3, 4) matrix.

    ``b_T`` is the unit tangent, ``b_O = f_m(x)``; ``b_N`` is ``normal0`` transported from ``x = 0``
    by the minimal rotation ``b_T(0) → b_T(x)`` and turned about ``b_T`` by ``twist · x``;
    ``b_B = b_N × b_T``.  See the module docstring for why this replaces ``Δ12 × Δ23``.

    Args:
        points: (3, 3) control points.
        stiffness: () ``a >= 2``.
        twist: () ``γ`` in radians.
        normal0: (3,) unit normal at ``x = 0`` (:func:`start_normal`).
        x: () spline parameter in [0, 1].

    Returns:
        (3, 4) matrix with columns ``b_N, b_B, b_T, b_O``.
    """
    fallback = _normalize(points[2] - points[0], jnp.array([0.0, 0.0, 1.0]))
    t0 = _normalize(points[1] - points[0], fallback)
    t = _normalize(spline_tangent(points, stiffness, x), t0)
    n = _rotate_minimal(t0, t, normal0)
    n = _normalize(n - jnp.dot(n, t) * t, _any_perpendicular(t))
    angle = twist * x
    n = jnp.cos(angle) * n + jnp.sin(angle) * jnp.cross(t, n)
    b = jnp.cross(n, t)
    return jnp.stack([n, b, t, spline_point(points, stiffness, x)], axis=1)


def frame_inverse(frame: jax.Array) -> jax.Array:
    """Inverse of an orthonormal frame ``[R | o]`` (3, 4): ``[R^T | -R^T o]`` (Eq. 5.6)."""
    rot_t = frame[:, :3].T
    return jnp.concatenate([rot_t, -(rot_t @ frame[:, 3])[:, None]], axis=1)


def _compose(a: jax.Array, b: jax.Array) -> jax.Array:
    """Affine (3, 4) product ``a · b``."""
    return jnp.concatenate([a[:, :3] @ b[:, :3], (a[:, :3] @ b[:, 3] + a[:, 3])[:, None]], axis=1)


def spline_frames(rig: SplineRig, pose: SplinePose, x: jax.Array) -> jax.Array:
    """Frames of every spline at parameters ``x``.

    Args:
        rig: the rig (for the reference normals).
        pose: the pose.
        x: (S,) parameters.

    Returns:
        (K, S, 3, 4) frames.
    """
    n0 = jax.vmap(start_normal)(rig.bind.points, rig.reference_normal, pose.points)
    per_spline = jax.vmap(spline_frame, in_axes=(None, None, None, None, 0))
    return jax.vmap(per_spline, in_axes=(0, 0, 0, 0, None))(
        pose.points, pose.stiffness, pose.twist, n0, x
    )


# ----------------------------------------------------------------------------------------------
# rig hierarchy (Fig. 5.16)
# ----------------------------------------------------------------------------------------------


def attach_children(rig: SplineRig, points: jax.Array) -> jax.Array:
    """Translate each child spline so its ``p1`` sits on its parent's attachment point.

    Args:
        rig: rig with ``parent`` / ``parent_point``.
        points: (K, 3, 3) control points whose children may be detached.

    Returns:
        (K, 3, 3) control points, parents processed before children.
    """
    out = [points[k] for k in range(rig.num_splines)]
    for k, (p, j) in enumerate(zip(rig.parent, rig.parent_point, strict=True)):
        if p >= 0:
            out[k] = out[k] + (out[p][j] - out[k][0])
    return jnp.stack(out)


def axis_angle_to_matrix(axis_angle: jax.Array) -> jax.Array:
    """Rodrigues rotation matrix (3, 3) of an axis-angle vector (3,), smooth at zero angle."""
    theta_sq = jnp.dot(axis_angle, axis_angle)
    small = theta_sq < 1e-8
    safe_sq = jnp.where(small, 1.0, theta_sq)
    theta = jnp.sqrt(safe_sq)
    # sin(θ)/θ and (1-cos θ)/θ² with their Taylor series near zero
    s = jnp.where(small, 1.0 - theta_sq / 6.0, jnp.sin(theta) / theta)
    c = jnp.where(small, 0.5 - theta_sq / 24.0, (1.0 - jnp.cos(theta)) / safe_sq)
    k = jnp.array(
        [
            [0.0, -axis_angle[2], axis_angle[1]],
            [axis_angle[2], 0.0, -axis_angle[0]],
            [-axis_angle[1], axis_angle[0], 0.0],
        ]
    )
    return jnp.eye(3) + s * k + c * (k @ k)


def forward_kinematics(
    rig: SplineRig,
    root_rotation: jax.Array,
    joint_rotation: jax.Array,
    *,
    twist: jax.Array | None = None,
    stiffness: jax.Array | None = None,
    translation: jax.Array | None = None,
) -> SplinePose:
    """Pose from joint rotations: each spline turns about ``p1`` and bends about ``p2``.

    A child inherits the rotation of the parent segment it hangs from (``parent_point`` 0 or 1:
    the first segment, 2: the second) and sits on the posed attachment point.

    Args:
        rig: the rig.
        root_rotation: (K, 3, 3) local rotation at ``p1`` (bind-world axes).
        joint_rotation: (K, 3, 3) local rotation at ``p2`` (bend of the second segment).
        twist: (K,) radians, default the bind twist.
        stiffness: (K,) default the bind stiffness.
        translation: (3,) offset of the root splines, default 0.

    Returns:
        The posed :class:`SplinePose`.
    """
    bind = rig.bind.points
    shift = jnp.zeros(3) if translation is None else translation
    seg1: list[jax.Array] = []
    seg2: list[jax.Array] = []
    pts: list[jax.Array] = []
    for k, (p, j) in enumerate(zip(rig.parent, rig.parent_point, strict=True)):
        if p >= 0:
            inherited = seg2[p] if j == 2 else seg1[p]
            p1 = pts[p][j] + inherited @ (bind[k, 0] - bind[p, j])
        else:
            inherited = jnp.eye(3)
            p1 = bind[k, 0] + shift
        g1 = inherited @ root_rotation[k]
        g2 = g1 @ joint_rotation[k]
        p2 = p1 + g1 @ (bind[k, 1] - bind[k, 0])
        p3 = p2 + g2 @ (bind[k, 2] - bind[k, 1])
        seg1.append(g1)
        seg2.append(g2)
        pts.append(jnp.stack([p1, p2, p3]))
    return SplinePose(
        points=jnp.stack(pts),
        stiffness=rig.bind.stiffness if stiffness is None else stiffness,
        twist=rig.bind.twist if twist is None else twist,
    )


# ----------------------------------------------------------------------------------------------
# binding (Eq. 5.5-5.6)
# ----------------------------------------------------------------------------------------------


def _foot_parameter(
    points: jax.Array, stiffness: jax.Array, vertex: jax.Array, iterations: int
) -> jax.Array:
    """Plane-based binary search for ``x`` with ``<b_T(x) | v - b_O(x)> = 0`` (Eq. 5.5)."""

    def step(carry, _):
        lo, hi = carry
        mid = 0.5 * (lo + hi)
        side = jnp.dot(
            spline_tangent(points, stiffness, mid), vertex - spline_point(points, stiffness, mid)
        )
        # side > 0: v lies behind the plane, the foot point is further along the spline
        lo = jnp.where(side > 0, mid, lo)
        hi = jnp.where(side > 0, hi, mid)
        return (lo, hi), None

    (lo, hi), _ = lax.scan(step, (jnp.float32(0.0), jnp.float32(1.0)), None, length=iterations)
    return 0.5 * (lo + hi)


def bind_vertex(
    rig: SplineRig,
    normal0: jax.Array,
    vertex: jax.Array,
    normal: jax.Array,
    spline: jax.Array,
    *,
    iterations: int = 24,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Bind one vertex to its splines (Eq. 5.5-5.6).

    Args:
        rig: the rig (bind pose).
        normal0: (K, 3) bind start normals (``rig.reference_normal``).
        vertex: (3,) bind-pose position ``v``.
        normal: (3,) unit normal.
        spline: (I,) spline indices.
        iterations: binary search steps; 24 resolves ``x`` to float32 precision.

    Returns:
        ``x`` (I,), ``v'`` (I, 3) and the normal in spline space (I, 3).
    """
    bind = rig.bind

    def one(k):
        pts, a, tw = bind.points[k], bind.stiffness[k], bind.twist[k]
        x = _foot_parameter(pts, a, vertex, iterations)
        frame = spline_frame(pts, a, tw, normal0[k], x)
        inv = frame_inverse(frame)
        return x, inv[:, :3] @ vertex + inv[:, 3], inv[:, :3] @ normal

    return jax.vmap(one)(spline)


def _validate_influences(spline_index, weights, num_vertices: int, num_splines: int):
    idx = np.asarray(spline_index)
    w = np.asarray(weights, dtype=np.float64)
    if idx.ndim == 1:
        idx = idx[:, None]
    if w.ndim == 1:
        w = w[:, None]
    if not np.issubdtype(idx.dtype, np.integer):
        raise TypeError(f"spline_index must be an integer array, got dtype {idx.dtype}")
    if idx.ndim != 2 or not 1 <= idx.shape[1] <= _MAX_INFLUENCES:
        raise ValueError(f"spline_index must have shape (V, I) with 1 <= I <= 3, got {idx.shape}")
    if idx.shape[0] != num_vertices:
        raise ValueError(
            f"spline_index has {idx.shape[0]} rows but vertices has {num_vertices} rows"
        )
    if w.shape != idx.shape:
        raise ValueError(f"weights shape {w.shape} does not match spline_index shape {idx.shape}")
    if np.any(idx < 0) or np.any(idx >= num_splines):
        raise ValueError(
            f"spline_index out of range [0, {num_splines}): min {idx.min()}, max {idx.max()}"
        )
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    sums = w.sum(axis=1)
    if np.any(np.abs(sums - 1.0) > 1e-4):
        bad = int(np.argmax(np.abs(sums - 1.0)))
        raise ValueError(
            f"weights must sum to one per vertex (Eq. 5.7; not renormalized): vertex {bad} sums "
            f"to {sums[bad]:.6f}"
        )
    return idx.astype(np.int32), w.astype(np.float32)


def bind_mesh(
    rig: SplineRig,
    vertices,
    spline_index,
    weights,
    *,
    normals=None,
    iterations: int = 24,
) -> SkinBinding:
    """Bind a mesh to the rig (Eq. 5.5-5.6), validating every argument first.

    Args:
        rig: the rig.
        vertices: (V, 3) finite bind-pose positions.
        spline_index: (V, I) ints in [0, K), I <= 3 (or (V,) for one influence).
        weights: (V, I) non-negative weights summing to one per row (not renormalized).
        normals: (V, 3) vertex normals, default ``+y`` (only needed to deform normals).
        iterations: binary search steps.

    Returns:
        The :class:`SkinBinding`.
    """
    v = np.asarray(vertices, dtype=np.float32)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices must be finite")
    idx, w = _validate_influences(spline_index, weights, v.shape[0], rig.num_splines)
    if normals is None:
        n = np.tile(np.array([[0.0, 1.0, 0.0]], np.float32), (v.shape[0], 1))
    else:
        n = np.asarray(normals, dtype=np.float32)
        if n.shape != v.shape:
            raise ValueError(f"normals shape {n.shape} does not match vertices shape {v.shape}")
        if not np.all(np.isfinite(n)):
            raise ValueError("normals must be finite")
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    if not isinstance(iterations, int) or iterations < 1:
        raise ValueError(f"iterations must be a positive int, got {iterations!r}")
    x, local, local_n = _bind_all(rig, jnp.asarray(v), jnp.asarray(n), jnp.asarray(idx), iterations)
    return SkinBinding(
        spline=jnp.asarray(idx),
        weight=jnp.asarray(w),
        x=x,
        local=local,
        local_normal=local_n,
        rest=jnp.asarray(v),
        rest_normal=jnp.asarray(n),
    )


@functools.partial(jax.jit, static_argnames=("iterations",))
def _bind_all(rig, vertices, normals, spline, iterations):
    # bind_mesh validates concrete arrays, so callers cannot jit it; it compiles its own core.
    return jax.vmap(
        lambda v, n, s: bind_vertex(rig, rig.reference_normal, v, n, s, iterations=iterations)
    )(vertices, normals, spline)


def brute_force_binding(
    points: np.ndarray, stiffness: float, vertices: np.ndarray, samples: int = 20001
) -> np.ndarray:
    """Slow NumPy reference: ``x`` of the nearest of ``samples`` points on the spline.

    Args:
        points: (3, 3) control points.
        stiffness: ``a``.
        vertices: (V, 3).
        samples: number of uniformly spaced parameters.

    Returns:
        (V,) parameters.
    """
    p = np.asarray(points, np.float64)
    xs = np.linspace(0.0, 1.0, samples)
    curve = (
        p[0]
        + (1 - (1 - xs) ** stiffness)[:, None] * (p[1] - p[0])
        + (xs**stiffness)[:, None] * (p[2] - p[1])
    )
    out = np.empty(len(vertices))
    for i, v in enumerate(np.asarray(vertices, np.float64)):
        out[i] = xs[np.argmin(np.sum((curve - v) ** 2, axis=1))]
    return out


# ----------------------------------------------------------------------------------------------
# deformation styles (Eq. 5.8-5.13)
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


def _check_style(style: Style) -> None:
    """Shape checks that work on traced styles too (values are checked by make_style)."""
    t, c = jnp.shape(style.textures), jnp.shape(style.curves)
    if len(t) != 3 or t[0] != 3 or t[1] < 2 or t[2] < 2:
        raise ValueError(f"style.textures must have shape (3, A, X) with A, X >= 2, got {t}")
    if len(c) != 2 or c[0] != 3 or c[1] < 2:
        raise ValueError(f"style.curves must have shape (3, X) with X >= 2, got {c}")


def identity_style(texture_shape: tuple[int, int] = (64, 32), curve_size: int = 32) -> Style:
    """The style whose textures and curves are all one: no change (Eq. 5.10)."""
    return make_style(np.ones((3, *texture_shape)), np.ones((3, curve_size)))


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


def _pose_weights(points: jax.Array, twist: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``β/π`` and ``|γ|/π`` of one spline."""
    return bend_angle(points) / math.pi, jnp.abs(twist) / math.pi


# ----------------------------------------------------------------------------------------------
# spline skinning (Eq. 5.7, 5.13)
# ----------------------------------------------------------------------------------------------


def _style_flags(styles: str) -> tuple[bool, bool]:
    if styles not in ("none", "radial", "rect", "both"):
        raise ValueError(f"styles must be 'none', 'radial', 'rect' or 'both', got {styles!r}")
    return styles in ("radial", "both"), styles in ("rect", "both")


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
    """Exact spline skinning of a whole mesh: vmap of :func:`skin_vertex_exact`; (V,3), (V,3)."""
    _style_flags(styles)
    if styles != "none" and style is None:
        raise ValueError("style is required when styles != 'none'")
    validate_pose(rig, pose)
    pose = jax.tree_util.tree_map(jnp.asarray, pose)
    style = None if style is None else jax.tree_util.tree_map(jnp.asarray, style)
    if style is not None:
        _check_style(style)
    n0 = jax.vmap(start_normal)(rig.bind.points, rig.reference_normal, pose.points)
    fn = lambda s, w, x, v, n: skin_vertex_exact(  # noqa: E731
        pose, n0, s, w, x, v, n, style, styles=styles, dominant_only=dominant_only
    )
    return jax.vmap(fn)(
        binding.spline, binding.weight, binding.x, binding.local, binding.local_normal
    )


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
    if not isinstance(samples, int) or samples < 2:
        raise ValueError(f"samples must be an int >= 2, got {samples!r}")
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
    if not isinstance(samples, int) or samples < 2:
        raise ValueError(f"samples must be an int >= 2, got {samples!r}")
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
    return pos, nrm * lax.rsqrt(jnp.maximum(jnp.sum(nrm * nrm), _EPS_SQ))


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
) -> tuple[jax.Array, jax.Array]:
    """Two-pass sampled spline skinning of a mesh (thesis 5.8), style on the dominant spline.

    Args:
        rig: the rig.
        pose: the pose.
        binding: from :func:`prepare_sampled` with the same ``samples``.
        style: the style (needed unless ``styles == 'none'``).
        samples: S per spline.
        styles: 'none', 'radial', 'rect' or 'both'.

    Returns:
        Positions (V, 3) and unit normals (V, 3).
    """
    radial, rect = _style_flags(styles)
    if (radial or rect) and style is None:
        raise ValueError("style is required when styles != 'none'")
    if not isinstance(binding, SampledBinding):
        raise TypeError("binding must be a SampledBinding (use prepare_sampled)")
    validate_pose(rig, pose)
    pose = jax.tree_util.tree_map(jnp.asarray, pose)
    skinning, style_table = sample_spline_frames(rig, pose, samples)
    pos, nrm = jax.vmap(lambda u, w, v, n: skin_vertex_sampled(skinning, u, w, v, n))(
        binding.coord, binding.weight, binding.rest, binding.rest_normal
    )
    if not (radial or rect):
        return pos, nrm
    style = jax.tree_util.tree_map(jnp.asarray, style)
    _check_style(style)
    dpos, dnrm = jax.vmap(
        lambda u, w, v, n: style_offset_sampled(
            style_table, style, samples, u, w, v, n, radial=radial, rect=rect
        )
    )(
        binding.dominant_coord,
        binding.dominant_weight,
        binding.dominant_local,
        binding.dominant_local_normal,
    )
    return pos + dpos, _normalize(nrm + dnrm, jnp.array([0.0, 1.0, 0.0]))


# ----------------------------------------------------------------------------------------------
# baselines driven by the same skeleton: LBS (SSD) and DQS
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


def _check_lbs_inputs(transforms, vertices, joints, weights):
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
    if j is not None and (j.min() < 0 or j.max() >= nj):
        raise ValueError(f"joints out of range [0, {nj})")
    w = _concrete(weights)
    if w is not None and (np.any(w < 0) or np.any(np.abs(w.sum(-1) - 1) > 1e-3)):
        raise ValueError("weights must be non-negative and sum to one per vertex")


def linear_blend_skinning(transforms, vertices, normals, joints, weights):
    """LBS of a mesh: vmap of :func:`lbs_vertex`; returns positions (V, 3) and normals (V, 3)."""
    _check_lbs_inputs(transforms, vertices, joints, weights)
    t = transforms[:, :3, :]
    fn = lambda j, w, v, n: lbs_vertex(t, j, w, v, n)  # noqa: E731
    return jax.vmap(fn)(joints, weights, vertices, normals)


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
    """DQS of a mesh: vmap of :func:`dqs_vertex`; returns positions (V, 3) and normals (V, 3)."""
    _check_lbs_inputs(transforms, vertices, joints, weights)
    dual = dual_quaternions(transforms[:, :3, :])
    return jax.vmap(lambda j, w, v, n: dqs_vertex(dual, j, w, v, n))(
        joints, weights, vertices, normals
    )


# ----------------------------------------------------------------------------------------------
# a small styled character for demos
# ----------------------------------------------------------------------------------------------


def limb_mesh(n_around: int, n_along: int, radius: float, length: float):
    """Closed, slightly tapered tube along +y from the origin (a demo limb).

    Returns:
        vertices (V, 3), outward normals (V, 3) float32 and faces (F, 3) int32 (outward).
    """
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    y = np.linspace(0.0, length, n_along)
    yy, aa = np.meshgrid(y, a, indexing="ij")
    # slightly tapered like a limb
    r = radius * (1.0 - 0.25 * yy / length)
    v = np.stack([r * np.cos(aa), yy, r * np.sin(aa)], -1).reshape(-1, 3)
    n = np.stack([np.cos(aa), 0 * yy, np.sin(aa)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_along - 1), np.arange(n_around), indexing="ij")
    a0 = (i * n_around + j).ravel()
    a1 = (i * n_around + (j + 1) % n_around).ravel()
    b0, b1 = a0 + n_around, a1 + n_around
    faces = np.concatenate([np.stack([a0, b1, a1], 1), np.stack([a0, b0, b1], 1)])
    base = len(v)
    v = np.concatenate([v, [[0.0, 0.0, 0.0], [0.0, length, 0.0]]])
    n = np.concatenate([n, [[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]]])
    ring0 = np.arange(n_around)
    ring1 = (n_along - 1) * n_around + ring0
    cap0 = np.stack([np.full(n_around, base), ring0, np.roll(ring0, -1)], 1)
    cap1 = np.stack([np.full(n_around, base + 1), np.roll(ring1, -1), ring1], 1)
    faces = np.concatenate([faces, cap0, cap1])
    return v.astype(np.float32), n.astype(np.float32), faces.astype(np.int32)


def muscle_style(strength: float = 0.35, size: tuple[int, int] = (16, 16)) -> Style:
    """A muscle bulge (Fig. 5.17/5.21): the frontal texture swells around ``x = 0.3`` on the
    ``α ≈ π`` side; lateral texture, radial texture and curves are identity."""
    rows, cols = size
    alpha = np.linspace(0.0, 1.0, rows)[:, None]
    x = np.linspace(0.0, 1.0, cols)[None, :]
    bump = np.exp(-(((x - 0.3) / 0.15) ** 2)) * np.clip((alpha - 0.4) / 0.6, 0.0, 1.0)
    textures = np.stack([1.0 + strength * bump, np.ones((rows, cols)), np.ones((rows, cols))])
    return make_style(textures, np.ones((3, cols)))


_skin_exact_jit = jax.jit(skin_exact, static_argnames=("styles", "dominant_only"))


def demo_character(phase: float = 0.25, *, styles: str = "both"):
    """A styled arm for demo scenes: one spline, bending and twisting with ``phase`` in [0, 1).

    The arm stands on the origin along +y (length 2, radius 0.22), bends about the x axis at its
    middle (up to about 115°) and carries :func:`muscle_style`.

    Returns:
        vertices (V, 3), faces (F, 3) int32 and unit normals (V, 3), NumPy arrays.
    """
    _style_flags(styles)
    v, n, faces = limb_mesh(24, 41, 0.22, 2.0)
    rig = make_rig(
        np.array([[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.0]]], np.float32),
        stiffness=4.0,
        reference_normal=[[1.0, 0.0, 0.0]],
    )
    binding = bind_mesh(rig, v, np.zeros((len(v), 1), np.int32), np.ones((len(v), 1)), normals=n)
    bend = 1.0 * (1.0 - math.cos(2 * math.pi * phase))
    rot = axis_angle_to_matrix(jnp.array([-bend, 0.0, 0.0], jnp.float32))
    pose = forward_kinematics(
        rig, jnp.eye(3)[None], rot[None], twist=jnp.array([0.6 * math.sin(2 * math.pi * phase)])
    )
    style = muscle_style() if styles != "none" else None
    # a demo entry point returning NumPy, so it compiles its own call (like bind_mesh)
    pos, nrm = _skin_exact_jit(rig, pose, binding, style, styles=styles)
    return np.asarray(pos), faces, np.asarray(nrm)
