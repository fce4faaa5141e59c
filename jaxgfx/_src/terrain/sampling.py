"""Any terrain: validation (Eq. 3.1) and sampling on a grid (thesis 3.4.3).

:func:`as_terrain` and :func:`check_terrain` accept every terrain kind of
``functions.py``, ``csg.py`` and ``heightmap.py`` (or a plain callable) and check the
``int32 (3,) -> bool ()`` contract of Eq. 3.1 before tracing; :func:`sample_terrain`
evaluates a terrain on a regular grid, taking a terrain's grid fast path when it has one.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.terrain.csg import CSGTerrain
from jaxgfx._src.terrain.functions import (
    _I32,
    Difference,
    FunctionTerrain,
    Intersection,
    SawTerrain,
    SinTerrain,
    Union,
    XorTerrain,
    _sample_points,
)
from jaxgfx._src.terrain.heightmap import HeightmapTerrain, VolumeTerrain, ground_height

__all__ = ["as_terrain", "check_terrain", "check_viewer", "sample_terrain"]


# --------------------------------------------------------------------------------------
# Validation (Eq. 3.1)
# --------------------------------------------------------------------------------------


_TERRAIN_TYPES = (
    XorTerrain,
    SawTerrain,
    SinTerrain,
    CSGTerrain,
    HeightmapTerrain,
    VolumeTerrain,
    FunctionTerrain,
    Union,
    Intersection,
    Difference,
)


def as_terrain(terrain) -> Any:
    """Returns ``terrain`` as a pytree terrain (plain callables are wrapped)."""
    if isinstance(terrain, _TERRAIN_TYPES):
        return terrain
    if callable(terrain):
        return FunctionTerrain(fn=terrain)
    raise TypeError(f"terrain must be a terrain object or a callable, got {type(terrain).__name__}")


def check_terrain(terrain, name: str = "terrain") -> Any:
    """Validates a terrain before tracing: one int32 (3,) point must give a bool scalar.

    Raises:
        TypeError: naming ``name`` when the output has the wrong shape or dtype.
    """
    terrain = as_terrain(terrain)
    try:
        out = jax.eval_shape(terrain, jax.ShapeDtypeStruct((3,), _I32))
    except Exception as err:
        raise TypeError(f"{name} failed on one int32 (3,) point: {err}") from err
    if not isinstance(out, jax.ShapeDtypeStruct) or out.shape != () or out.dtype != jnp.bool_:
        got = (getattr(out, "shape", None), getattr(out, "dtype", type(out).__name__))
        raise TypeError(
            f"{name} must map one int32 (3,) point to a bool scalar (Eq. 3.1), "
            f"got shape/dtype {got}"
        )
    return terrain


def check_viewer(terrain, viewer, *, name: str = "viewer") -> tuple[int, int, int]:
    """Checks that the integer ``viewer`` (x, y, z) is in air, not inside solid ground.

    A viewer inside the terrain sees the inside of the surface (a ceiling); callers
    that want it anyway skip this check.

    Returns:
        ``viewer`` as three Python ints.

    Raises:
        ValueError: naming ``name`` when it is not three integers or is inside the
            terrain (for a height map the message gives the lowest free y).
    """
    v = np.asarray(viewer)
    if v.shape != (3,) or not np.issubdtype(v.dtype, np.integer):
        raise ValueError(f"{name} must be 3 integers (x, y, z), got {viewer!r}")
    if np.any(np.abs(v.astype(np.int64)) > 2**31 - 1):
        raise ValueError(f"{name} {tuple(int(a) for a in v)} is outside the int32 world")
    p = (int(v[0]), int(v[1]), int(v[2]))
    terrain = check_terrain(terrain)
    if bool(terrain(jnp.asarray(p, _I32))):
        hint = ""
        if isinstance(terrain, HeightmapTerrain):
            g = float(ground_height(terrain, p[0] + 0.5, p[2] + 0.5))
            hint = f"; the lowest free y there is {int(np.ceil(g - 0.5))}"
        raise ValueError(f"{name} {p} is inside solid ground{hint}")
    return p


# --------------------------------------------------------------------------------------
# Sampling on a grid (3.4.3)
# --------------------------------------------------------------------------------------


def sample_terrain(terrain, origin: jax.Array, *, level, shape: tuple[int, int, int]):
    """Samples ``terrain`` at ``origin + i 2^level`` for i in ``shape`` (3.4.3).

    Terrains with a ``sample_grid(origin, level, shape)`` method (the binned CSG)
    take their grid fast path when ``level`` is a Python int; combinators recurse
    into their operands; everything else is ``vmap`` over the points.

    Args:
        terrain: a terrain pytree (validate with :func:`check_terrain` first).
        origin: (3,) int32 world coordinate of sample (0, 0, 0).
        level: voxel level: a static int (fast paths) or a () int32 (may be traced).
        shape: static grid shape.
    Returns:
        ``shape`` bool.
    """
    if isinstance(terrain, (Union, Intersection, Difference)):
        a = sample_terrain(terrain.a, origin, level=level, shape=shape)
        b = sample_terrain(terrain.b, origin, level=level, shape=shape)
        if isinstance(terrain, Union):
            return a | b
        return a & b if isinstance(terrain, Intersection) else a & ~b
    grid = getattr(terrain, "sample_grid", None)
    if grid is not None and isinstance(level, (int, np.integer)) and not isinstance(level, bool):
        out = grid(origin, int(level), tuple(shape))
        if out is not None:
            return out
    return _sample_points(terrain, origin, level, shape)
