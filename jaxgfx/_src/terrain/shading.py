"""Terrain colours by slope and height, fog to the horizon and a sky (thesis 3.5.2, HVOX shader).

The thesis's engine textures the terrain by blending colour textures with weights,
multiplies a detail texture onto them and fades to a fog colour by distance (the
HVOX shader, ``/work/shared/data/README.md``).  Here the weights come from the
surface itself: grass low, earth higher, rock where the slope is steep and snow high
and flat, with a smooth position-hashed detail term instead of a detail texture, so
every vertex gets its colour from its position and normal alone (no texture lookups)
and the colours are continuous across Clip-Box levels.  :func:`render_terrain` draws
the nested levels with these colours, one-sided sun plus sky light, distance fog that
fades into the sky behind each pixel by the outer box, and the sky itself.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_float

__all__ = ["terrain_colors", "render_terrain", "SKY_HORIZON", "SKY_ZENITH", "DETAIL_PERIOD"]

_F32 = jnp.float32
SKY_HORIZON = (0.80, 0.85, 0.90)
"""The sky at the horizon; far terrain fades into the sky colour behind each pixel."""
SKY_ZENITH = (0.32, 0.52, 0.82)

_GRASS = (0.29, 0.40, 0.17)
_EARTH = (0.50, 0.44, 0.31)
_ROCK = (0.50, 0.44, 0.39)
_ROCK_BAND = (0.68, 0.40, 0.25)  # iron-red strata alternate with grey rock
_SNOW = (0.86, 0.88, 0.92)


def _smoothstep(lo: float, hi: float, x: jax.Array) -> jax.Array:
    t = jnp.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


DETAIL_PERIOD = 1000
"""The detail field repeats every this many voxels on each axis: its waves have whole
numbers of cycles per period, so it is computed from the integer world coordinates
(reduced modulo the period in int32, as the terrain functions of Eq. 3.2 are) plus a
small float offset, and two views a multiple of the period apart (SAW's modulus, a
tiled map's period times 1000, 10^9) get the same colours, bit for bit."""

# (cycles per period along x, y, z; phase) of each wave, and its weight
_WAVES = (
    ((18, 8, 11), 0.0, 1.0),
    ((-14, 0, 9), 1.7, 1.0),
    ((49, 32, -43), 4.1, 0.5),
    ((59, 0, 37), 2.3, 0.5),
)
_BAND = 72  # strata: cycles per period along y (about 14 voxels apart)


def _phase(origin: jax.Array, rel: jax.Array, k: tuple[int, int, int]) -> jax.Array:
    """``2 pi (k . (origin + rel)) / DETAIL_PERIOD``: the integer part exact in int32.

    Args:
        origin: (3,) int32 world position; rel: (V, 3) float32 offsets from it.
    """
    o = jnp.remainder(jnp.asarray(origin, jnp.int32), DETAIL_PERIOD)
    whole = jnp.remainder(k[0] * o[0] + k[1] * o[1] + k[2] * o[2], DETAIL_PERIOD)
    frac = k[0] * rel[:, 0] + k[1] * rel[:, 1] + k[2] * rel[:, 2]
    return (whole.astype(_F32) + frac) * _F32(2.0 * np.pi / DETAIL_PERIOD)


def _detail(origin: jax.Array, rel: jax.Array) -> jax.Array:
    """A smooth pseudo-random field in [-1, 1] of world position (the detail texture's role).

    Sums of waves at unrelated frequencies: continuous, so two levels' vertices at the
    same place get the same value (no seam), cheap on any backend, and exact far from
    the origin (see :data:`DETAIL_PERIOD`).
    """
    n = jnp.zeros(rel.shape[:1], _F32)
    for k, ph, w in _WAVES:
        n = n + w * jnp.sin(_phase(origin, rel, k) + ph)
    return n / 3.0


def terrain_colors(
    vertices,
    normals,
    *,
    height_range: tuple[float, float],
    snow_line: float | None = 0.8,
    rock_slope: tuple[float, float] = (0.3, 0.55),
    origin=None,
) -> jax.Array:
    """Per-vertex terrain colour from height and slope: grass, earth, rock, snow.

    With ``t`` the height's fraction of ``height_range`` and ``s = 1 - n_y`` the slope
    (0 flat, 1 vertical): grass at the bottom turns to earth towards the top, rock
    (with strata bands every few voxels) takes over where ``s`` passes ``rock_slope``,
    and snow covers flat ground above ``snow_line``; a smooth detail field of the
    position jitters the boundaries and the brightness so the bands do not look ruled.

    Args:
        vertices: (V, 3) positions in voxels (y up) relative to ``origin``.
        normals: (V, 3) unit normals (zeros are treated as flat).
        height_range: (low, high) world y mapped to t = 0 and 1 (e.g. a height map's
            ``base`` and ``base + relief``).
        snow_line: t above which flat ground is snow; None for none.
        rock_slope: slopes (1 - n_y) where rock starts and is complete.
        origin: (3,) int32 world position the vertices are relative to (a viewer or box
            origin); None: the world origin (``vertices`` are world positions).  The
            colours are a function of the integer world position plus the offset, so
            they do not degrade far from the world origin.
    Returns:
        (V, 3) float32 RGB in [0, 1].

    Raises:
        ValueError: ``height_range`` is not (low, high) with low < high, or bad shapes.
    """
    v = jnp.asarray(vertices, _F32)
    n = jnp.asarray(normals, _F32)
    if v.ndim != 2 or v.shape[-1] != 3 or n.shape != v.shape:
        raise ValueError(f"vertices and normals must both be (V, 3), got {v.shape} and {n.shape}")
    if len(height_range) != 2:
        raise ValueError(f"height_range must be (low, high), got {height_range!r}")
    lo = check_float("height_range[0]", height_range[0])
    hi = check_float("height_range[1]", height_range[1])
    if not hi > lo:
        raise ValueError(f"height_range must have low < high, got {height_range!r}")
    if snow_line is not None:
        snow_line = check_float("snow_line", snow_line)
    r0, r1 = (check_float("rock_slope", s, low=0.0, high=1.0) for s in rock_slope)
    if not r1 > r0:
        raise ValueError(f"rock_slope must be (start, full) with start < full, got {rock_slope}")

    o = jnp.zeros(3, jnp.int32) if origin is None else jnp.asarray(origin, jnp.int32)
    if o.shape != (3,):
        raise ValueError(f"origin must be (3,) integers, got shape {o.shape}")
    d = _detail(o, v)
    # world y - lo with the integer parts subtracted in int32
    lo_i = int(np.floor(lo))
    y = (o[1] - lo_i).astype(_F32) + (v[:, 1] - _F32(lo - lo_i))
    t = y / (hi - lo) + 0.04 * d
    ny = jnp.where(jnp.sum(n * n, -1) > 0, n[:, 1], 1.0)
    slope = 1.0 - jnp.clip(ny, 0.0, 1.0) + 0.05 * d
    col = lambda c: jnp.asarray(c, _F32)  # noqa: E731
    soil = col(_GRASS) + (col(_EARTH) - col(_GRASS)) * _smoothstep(0.2, 0.7, t)[:, None]
    band = 0.5 + 0.5 * jnp.sin(_phase(o, v, (0, _BAND, 0)) + 2.0 * d)
    rock = col(_ROCK) + (col(_ROCK_BAND) - col(_ROCK)) * (0.8 * band)[:, None]
    c = soil + (rock - soil) * _smoothstep(r0, r1, slope)[:, None]
    if snow_line is not None:
        flat = 1.0 - _smoothstep(0.3, 0.55, slope)
        snow = _smoothstep(snow_line, snow_line + 0.06, t) * flat
        c = c + (col(_SNOW) - c) * snow[:, None]
    c = c * (1.0 + 0.12 * d)[:, None]
    return jnp.clip(c, 0.0, 1.0)


_colors_jit = jax.jit(terrain_colors, static_argnames=("height_range", "snow_line", "rock_slope"))


def _pad_pow2(a: np.ndarray, minimum: int = 1024) -> np.ndarray:
    """``a`` with zero rows appended up to the next power of two >= ``minimum`` rows."""
    cap = max(minimum, 1 << int(np.ceil(np.log2(max(a.shape[0], 1)))))
    out = np.zeros((cap,) + a.shape[1:], a.dtype)
    out[: a.shape[0]] = a
    return out


def render_terrain(
    cam,
    levels: Sequence[dict],
    anchor,
    *,
    height_range: tuple[float, float],
    fog_distance: float | None,
    light_dir=(0.5, 0.75, 0.35),
    snow_line: float | None = 0.8,
    rasterize_fn=None,
):
    """Draws the nested levels coloured by :func:`terrain_colors`, fogged, over a sky.

    Args:
        cam: :class:`jaxgfx.camera.Camera`, position relative to ``anchor``.
        levels: ``level_views(state)`` (or a :class:`GeometryWorker` buffer's levels).
        anchor: (3,) integer world position the camera and vertices are relative to.
        height_range: (low, high) WORLD y for the colour bands.
        fog_distance: camera depth (voxels) where the fog reaches 95 %; the outer box's
            half-width hides the box edge in the sky behind it.  None: no fog.
        light_dir: direction towards the sun.
        snow_line: as in :func:`terrain_colors`.
        rasterize_fn: a jitted ``jaxgfx.raster.rasterize`` (default: jit it here).
    Returns:
        :class:`jaxgfx.compose.Frame` (colour with the sky, depth +inf on the sky).
    """
    from jaxgfx._src.compose import Frame, background
    from jaxgfx._src.raster import rasterize
    from jaxgfx._src.terrain.display import level_arrays

    if fog_distance is not None:
        fog_distance = check_float("fog_distance", fog_distance)
        if fog_distance <= 0:
            raise ValueError(f"fog_distance must be > 0 or None, got {fog_distance}")
    anchor = np.asarray(anchor, np.int64)
    v, n, f, _ = level_arrays(levels, anchor)
    # Padded to power-of-two lengths with unused vertices and degenerate (0, 0, 0)
    # triangles, which draw nothing: frames of a flythrough then share a few compiled
    # shapes instead of compiling the rasterizer once per triangle count.
    v, n, f = _pad_pow2(v), _pad_pow2(n), _pad_pow2(f)
    colors = _colors_jit(
        v,
        n,
        height_range=tuple(float(h) for h in height_range),
        snow_line=snow_line,
        origin=jnp.asarray(anchor, jnp.int32),
    )
    fn = rasterize_fn if rasterize_fn is not None else jax.jit(rasterize)
    out = fn(cam, jnp.asarray(v), jnp.asarray(f), jnp.concatenate([colors, jnp.asarray(n)], -1))
    albedo, nrm = out.color[..., :3], out.color[..., 3:]
    nn = jnp.sum(nrm * nrm, -1, keepdims=True)
    nrm = nrm / jnp.sqrt(jnp.where(nn > 0, nn, 1.0))
    light = jnp.asarray(light_dir, _F32)
    light = light / jnp.linalg.norm(light)
    sun = jnp.maximum(jnp.sum(nrm * light, -1, keepdims=True), 0.0)
    sky = 0.5 + 0.5 * nrm[..., 1:2]  # hemisphere light: facing up sees more sky
    lit = albedo * (0.7 * sun + 0.45 * sky)
    hit = jnp.isfinite(out.depth)
    # below the horizon, where no box reaches, the "ground" is the horizon colour
    sky_frame = background(cam, horizon=SKY_HORIZON, zenith=SKY_ZENITH, ground=SKY_HORIZON)
    if fog_distance is None:
        color = lit
    else:
        z = jnp.where(hit, out.depth, 0.0) / fog_distance
        k = (1.0 - jnp.exp(-3.0 * z * z * z))[..., None]  # clear near, 95 % at fog_distance
        # far terrain fades into the sky behind it, not into one colour: no grey cut-outs
        color = lit * (1.0 - k) + sky_frame.color * k
    return Frame(jnp.where(hit[..., None], color, sky_frame.color), out.depth)
