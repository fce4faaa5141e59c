"""Numerically safe vector helpers shared by the skinning modules (no thesis section).

Each helper works on one item and stays finite to differentiate: where a formula is singular (zero
length, opposite directions) the unsafe input is replaced inside the branch that is not taken (the
double-where trick), so neither the value nor the gradient of the untaken branch is NaN.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

__all__: list[str] = []  # private helpers only; the chapter's names live in the other modules

# Squared lengths below this count as zero (float32: lengths ~1e-6 of a unit-sized rig).
_EPS_SQ = 1e-12


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


# ----------------------------------------------------------------------------------------------
# affine (3, 4) matrices and concrete values
# ----------------------------------------------------------------------------------------------


def _compose(a: jax.Array, b: jax.Array) -> jax.Array:
    """Affine (3, 4) product ``a · b``."""
    return jnp.concatenate([a[:, :3] @ b[:, :3], (a[:, :3] @ b[:, 3] + a[:, 3])[:, None]], axis=1)


def _concrete(x) -> np.ndarray | None:
    """NumPy view of ``x`` if it is concrete (not a tracer), else ``None``."""
    if isinstance(x, jax.core.Tracer):
        return None
    return np.asarray(x)
