"""Spline binding: foot point and bind-space coordinates per vertex (thesis 5.4.3, Eq. 5.5-5.6).

A vertex bound to spline k stores the parameter ``x`` of the point on the spline whose normal
plane holds the vertex (Eq. 5.5, found by binary search) and its coordinates ``v' = B'(x)^{-1} v``
in that bind frame (Eq. 5.6); skinning later maps ``v'`` by the posed frame (Eq. 5.7).

**Weights** must be non-negative and sum to one per vertex (Eq. 5.7); they are checked, not
renormalized.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxgfx._src.checks import check_int, checking, require_finite, require_indices
from jaxgfx._src.skin.rig import SplineRig
from jaxgfx._src.skin.spline import frame_inverse, spline_frame, spline_point, spline_tangent

__all__ = ["SkinBinding", "bind_vertex", "bind_mesh", "brute_force_binding", "require_binding"]

# A vertex follows at most this many splines.
_MAX_INFLUENCES = 3


class SkinBinding(NamedTuple):
    """Per-vertex binding to up to three splines (Eq. 5.5-5.7), I = influences per vertex."""

    spline: jax.Array  # shape=(V, I), dtype=int32, spline index of each influence
    weight: jax.Array  # shape=(V, I), dtype=float32, skinning weights w_i, rows sum to 1
    x: jax.Array  # shape=(V, I), dtype=float32, spline parameter of the foot point (Eq. 5.5)
    local: jax.Array  # shape=(V, I, 3), dtype=float32, v' = B'^{-1} v (Eq. 5.6)
    local_normal: jax.Array  # shape=(V, I, 3), dtype=float32, normal in bind spline space
    rest: jax.Array  # shape=(V, 3), dtype=float32, bind-pose vertex v
    rest_normal: jax.Array  # shape=(V, 3), dtype=float32, bind-pose unit normal


# ----------------------------------------------------------------------------------------------
# binding one vertex (Eq. 5.5-5.6)
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


# ----------------------------------------------------------------------------------------------
# binding a mesh, with argument checks
# ----------------------------------------------------------------------------------------------


@functools.partial(jax.jit, static_argnames=("iterations",))
def _bind_all(rig, vertices, normals, spline, iterations):
    # bind_mesh validates concrete arrays, so callers cannot jit it; it compiles its own core.
    return jax.vmap(
        lambda v, n, s: bind_vertex(rig, rig.reference_normal, v, n, s, iterations=iterations)
    )(vertices, normals, spline)


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
    iterations = check_int("iterations", iterations, low=1)
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


# ----------------------------------------------------------------------------------------------
# reference for tests
# ----------------------------------------------------------------------------------------------


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


def require_binding(binding: SkinBinding, num_splines: int, where: str | None = None) -> None:
    """Inside :func:`~jaxgfx.checks.checked`: the binding values a mesh goes wrong from.

    A spline index out of range is clamped by the gathers (the vertex follows another
    spline), a NaN weight or coordinate moves its vertex to NaN.
    """
    if not checking():
        return
    require_indices("binding.spline", binding.spline, num_splines, "splines", where)
    for name in ("weight", "x", "local", "local_normal", "rest", "rest_normal"):
        require_finite(f"binding.{name}", getattr(binding, name), where)
