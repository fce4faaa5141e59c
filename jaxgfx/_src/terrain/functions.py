"""Terrain functions ``f: Z^3 -> {0, 1}`` (thesis 3.4.3, 3.5.3, Eq. 3.1-3.2).

A terrain takes one integer world coordinate ``(x, y, z)`` (int32, y up) and returns
a bool (solid or air) (Eq. 3.1).  Every terrain is a frozen dataclass pytree with
``__call__(p)`` written for ONE point; sampling batches it with ``jax.vmap``
(:func:`_sample_points` here, the dispatcher :func:`jaxgfx.terrain.sample_terrain`).
World coordinates are int32 voxel indices of the finest level, so the terrain is the
same, exactly, at x = 0 and at x = 10^9; floats only appear relative to a box origin
or to the viewer (3.5.3, "unlimited terrain size").

This module holds the analytic functions of Eq. 3.2 (XOR, SAW, SIN with the exact
:func:`int_sin`), user callables (:class:`FunctionTerrain`) and the Boolean
combinators; the binned CSG terrain is in ``csg.py``, terrains from data in
``heightmap.py``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import static_field

__all__ = [
    "XorTerrain",
    "SawTerrain",
    "SinTerrain",
    "int_sin",
    "FunctionTerrain",
    "Union",
    "Intersection",
    "Difference",
]

_I32 = jnp.int32


def _floormod(a, m):
    """Mathematical (floor) modulo for int32 arrays; the sign follows ``m``."""
    return jnp.remainder(a, m)


# --------------------------------------------------------------------------------------
# Analytic terrains of Eq. 3.2 (exact on int32)
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class XorTerrain:
    """``f_XOR(x, y, z) = ((x xor y xor z) mod modulus < threshold)`` (Eq. 3.2).

    ``mod`` is the mathematical (floor) modulo, exact on int32 (the xor of
    sign-extended int32 values equals the sign extension of the int32 xor).
    """

    modulus: int = static_field(1000)
    threshold: int = static_field(357)

    def __call__(self, p: jax.Array) -> jax.Array:
        p = jnp.asarray(p, _I32)
        v = jnp.bitwise_xor(jnp.bitwise_xor(p[0], p[1]), p[2])
        return _floormod(v, self.modulus) < self.threshold


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SawTerrain:
    """``f_SAW(x, y, z) = ((x + y + z) mod modulus < threshold)`` (Eq. 3.2).

    Each coordinate is reduced first, so the sum never overflows int32 and the
    result equals the exact integer value for every int32 coordinate.
    """

    modulus: int = static_field(1000)
    threshold: int = static_field(500)

    def __call__(self, p: jax.Array) -> jax.Array:
        r = _floormod(jnp.asarray(p, _I32), self.modulus)
        return _floormod(r[0] + r[1] + r[2], self.modulus) < self.threshold


def _sin_cos_tables() -> tuple[np.ndarray, np.ndarray]:
    """sin/cos of ``h 2^20``, ``m 2^10`` and ``l`` (float64 -> float32), stacked (3, 4096)."""
    h = np.arange(-2048, 2048, dtype=np.float64) * 2.0**20
    m = np.arange(1024, dtype=np.float64) * 2.0**10
    l_ = np.arange(1024, dtype=np.float64)
    pad = lambda a: np.concatenate([a, np.zeros(4096 - a.size)])  # noqa: E731
    ang = [h, pad(m), pad(l_)]
    # np.sin of an exactly representable float64 integer is correctly reduced by libm.
    return (
        np.stack([np.sin(a) for a in ang]).astype(np.float32),
        np.stack([np.cos(a) for a in ang]).astype(np.float32),
    )


def int_sin(x: jax.Array) -> jax.Array:
    """``sin(x)`` of an int32 ``x`` with absolute error ~3e-7 for every int32.

    ``x = h 2^20 + m 2^10 + l`` exactly; the three angles come from float64
    tables and are combined with the angle-addition formula, so the accuracy does
    not degrade far from the origin (a float32 ``sin(1e9)`` would be meaningless).
    """
    x = jnp.asarray(x, _I32)
    s_np, c_np = _sin_cos_tables()
    s_tab, c_tab = jnp.asarray(s_np), jnp.asarray(c_np)
    h = jnp.right_shift(x, 20) + 2048
    m = jnp.bitwise_and(jnp.right_shift(x, 10), 1023)
    lo = jnp.bitwise_and(x, 1023)
    sh, ch = s_tab[0, h], c_tab[0, h]
    sm, cm = s_tab[1, m], c_tab[1, m]
    sl, cl = s_tab[2, lo], c_tab[2, lo]
    s_hm = sh * cm + ch * sm
    c_hm = ch * cm - sh * sm
    return s_hm * cl + c_hm * sl


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SinTerrain:
    """``f_SIN(x, y, z) = (sin x + sin y + sin z < threshold)`` (Eq. 3.2), integer arguments."""

    threshold: float = static_field(2.0)

    def __call__(self, p: jax.Array) -> jax.Array:
        p = jnp.asarray(p, _I32)
        return int_sin(p[0]) + int_sin(p[1]) + int_sin(p[2]) < self.threshold


# --------------------------------------------------------------------------------------
# User functions and Boolean combinators
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FunctionTerrain:
    """Wraps a user callable ``fn(p: int32 (3,)) -> bool ()`` (static, hashed by identity)."""

    fn: Callable[[jax.Array], jax.Array] = static_field()

    def __call__(self, p: jax.Array) -> jax.Array:
        return self.fn(p)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Union:
    """``a or b``."""

    a: Any
    b: Any

    def __call__(self, p):
        return self.a(p) | self.b(p)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Intersection:
    """``a and b``."""

    a: Any
    b: Any

    def __call__(self, p):
        return self.a(p) & self.b(p)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Difference:
    """``a and not b``."""

    a: Any
    b: Any

    def __call__(self, p):
        return self.a(p) & ~self.b(p)


# --------------------------------------------------------------------------------------
# Sampling one terrain on a grid, point by point (3.4.3)
# --------------------------------------------------------------------------------------


def _sample_points(terrain, origin, level, shape):
    """``terrain`` at ``origin + i 2^level`` for i in ``shape``: ``vmap`` over the points.

    The generic path of :func:`jaxgfx.terrain.sample_terrain`, also the fallback of
    :meth:`CSGTerrain.sample_grid`; it lives here so both import it downward.
    """
    idx = [jnp.arange(n, dtype=_I32) << level for n in shape]
    gx, gy, gz = jnp.meshgrid(*idx, indexing="ij")
    pts = jnp.stack([gx, gy, gz], axis=-1).reshape(-1, 3) + jnp.asarray(origin, _I32)
    return jax.vmap(terrain)(pts).reshape(shape)
