"""Rotations as quaternions: yaw/pitch/roll, matrices and back (the camera's orientation).

A quaternion ``(w, x, y, z)`` of any non-zero length stands for one rotation; the matrix is
scaled by ``2 / |q|^2`` rather than normalised, so a gradient step on the quaternion never
leaves the rotations and no orientation is singular.  The helpers take ``xp`` (jnp or
NumPy) so constructors compute in float64 NumPy and round once, and traced code in jnp.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = [
    "yaw_pitch_roll_rotation",
    "rotation_matrix",
    "rotation_quaternion",
    "quaternion_of_angles",
    "quaternion_of_matrix",
]


def _qmul(a, b, xp=jnp):
    """Hamilton product of quaternions (..., 4) ``(w, x, y, z)`` (``xp``: jnp or NumPy)."""
    aw, ax, ay, az = (a[..., k] for k in range(4))
    bw, bx, by, bz = (b[..., k] for k in range(4))
    return xp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def yaw_pitch_roll_rotation(yaw, pitch, roll) -> jax.Array:
    """The rotation quaternion (..., 4) of yaw, pitch and roll in radians.

    ``yaw`` turns about world +y, then ``pitch`` tilts the view up about the camera's
    right axis, then ``roll`` turns about the view axis (the image clockwise).  At
    ``(0, 0, 0)`` the camera looks along +z with world +y up on screen.  Differentiable;
    the angles broadcast against each other.
    """
    yaw, pitch, roll = jnp.broadcast_arrays(
        *(jnp.asarray(v, jnp.result_type(float, v)) for v in (yaw, pitch, roll))
    )
    return quaternion_of_angles(yaw, pitch, roll, jnp)


def quaternion_of_angles(yaw, pitch, roll, xp):
    """:func:`yaw_pitch_roll_rotation` of broadcast arrays, in ``xp`` (jnp or NumPy)."""
    zero = xp.zeros_like(yaw)
    q_yaw = xp.stack([xp.cos(0.5 * yaw), zero, xp.sin(0.5 * yaw), zero], axis=-1)
    # Looking up turns forward (+z) towards +y: a rotation about +x by -pitch.
    q_pitch = xp.stack([xp.cos(0.5 * pitch), -xp.sin(0.5 * pitch), zero, zero], axis=-1)
    # OpenCV axes at rest are (-x, -y, +z) in the world: half a turn about z, plus roll.
    q_roll = xp.stack([-xp.sin(0.5 * roll), zero, zero, xp.cos(0.5 * roll)], axis=-1)
    return _qmul(_qmul(q_yaw, q_pitch, xp), q_roll, xp)


def rotation_matrix(q) -> jax.Array:
    """The 3x3 rotation (..., 3, 3) of quaternions (..., 4) ``(w, x, y, z)`` of any length.

    Scaled by ``2 / |q|^2`` rather than normalised by a square root, so the matrix is
    exactly the same for ``q`` and ``s q`` and smooth everywhere but ``q = 0`` (where it is
    the identity, finite, for a degenerate input).
    """
    q = jnp.asarray(q)
    w, x, y, z = (q[..., k] for k in range(4))
    n2 = w * w + x * x + y * y + z * z
    s = jnp.where(n2 > 0, 2.0 / jnp.where(n2 > 0, n2, 1.0), 0.0)
    rows = [
        [1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)],
        [s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x)],
        [s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def rotation_quaternion(m) -> jax.Array:
    """The unit quaternion (..., 4) ``(w, x, y, z)`` of rotation matrices (..., 3, 3).

    Shepperd's method: of the four formulas, each matrix uses the one whose divisor is
    largest, so the result is accurate for every rotation (a half turn included).
    The sign is chosen with ``w >= 0``.
    """
    return quaternion_of_matrix(jnp.asarray(m), jnp)


def quaternion_of_matrix(m, xp):
    """:func:`rotation_quaternion` in ``xp`` (jnp or NumPy)."""
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    a21, a02, a10 = (
        m[..., 2, 1] - m[..., 1, 2],
        m[..., 0, 2] - m[..., 2, 0],
        m[..., 1, 0] - m[..., 0, 1],
    )
    s01, s02, s12 = (
        m[..., 0, 1] + m[..., 1, 0],
        m[..., 0, 2] + m[..., 2, 0],
        m[..., 1, 2] + m[..., 2, 1],
    )
    lead = [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22]
    # Candidate k is 4 q_k q: each is exact, the largest q_k divides least.
    cand = xp.stack(
        [
            xp.stack([lead[0], a21, a02, a10], axis=-1),
            xp.stack([a21, lead[1], s01, s02], axis=-1),
            xp.stack([a02, s01, lead[2], s12], axis=-1),
            xp.stack([a10, s02, s12, lead[3]], axis=-1),
        ],
        axis=-2,
    )
    k = xp.argmax(xp.stack(lead, axis=-1), axis=-1)
    q = xp.take_along_axis(cand, k[..., None, None], axis=-2)[..., 0, :]
    q = q / xp.linalg.norm(q, axis=-1, keepdims=True)
    return xp.where(q[..., :1] < 0, -q, q)
