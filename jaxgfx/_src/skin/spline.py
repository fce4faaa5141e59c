"""Stiffness splines and their frames (thesis 5.4.1-5.4.2, Eq. 5.1-5.4).

Each function is written for one spline (three control points) and one parameter ``x`` in
[0, 1]; :func:`spline_frames` batches them over a rig's splines with :func:`jax.vmap`.

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
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxgfx._src.skin.geometry import (
    _any_perpendicular,
    _normalize,
    _pow01,
    _rotate_minimal,
    _safe_norm,
)
from jaxgfx._src.skin.rig import SplinePose, SplineRig

__all__ = [
    "bezier_point",
    "bezier_tangent",
    "spline_point",
    "spline_tangent",
    "bend_angle",
    "start_normal",
    "spline_frame",
    "frame_inverse",
    "spline_frames",
]


# ----------------------------------------------------------------------------------------------
# splines (Eq. 5.1-5.3)
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


# ----------------------------------------------------------------------------------------------
# frames (Eq. 5.4, 5.6)
# ----------------------------------------------------------------------------------------------


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
