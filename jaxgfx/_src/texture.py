"""UV textures: mip-mapped, filtered lookups that are differentiable in the texture and the UVs.

A rasterized frame interpolates each vertex's UV to its pixels (``rasterize``'s attributes);
:func:`texture` reads the texture there, as a GPU's sampler does (and nvdiffrast's
``texture`` op): bilinear within a level, linear between the two mip levels whose texel
size brackets the pixel's footprint in the texture (trilinear filtering, Williams 1983).
The footprint comes from :func:`uv_footprint`, the UVs' change from a pixel to its
neighbours on the same triangle (a GPU's derivatives over a 2x2 quad).

Conventions: ``uv = (0, 0)`` is the image's top-left corner and ``(1, 1)`` its bottom-right
(glTF's); texel ``(i, j)``'s centre is at ``((i + 0.5) / W, (j + 0.5) / H)``.  OBJ files
count v upwards: :func:`jaxgfx.io.mesh_texture` flips them on reading.  Outside
``[0, 1]`` the texture repeats (``wrap="repeat"``, glTF's default) or its edge texels
extend (``"clamp"``).

Gradients: with respect to the texels (every level of the pyramid, so a fit of the base
image goes through :func:`mip_pyramid`'s box filters) and to the UVs through the bilinear
weights.  The mip level is chosen without a gradient, as nvdiffrast does by default.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import check_finite, check_int, require_finite, static_field
from jaxgfx._src.eager import compiled_when_eager

__all__ = ["MipTexture", "mip_pyramid", "texture", "sample_bilinear", "uv_footprint"]

WRAPS = ("repeat", "clamp")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class MipTexture:
    """A texture and its mip levels, packed into one array.

    Attributes:
        texels: (T, C) float32, every level's texels row by row, level 0 first.
        sizes: static tuple of ``(height, width)`` per level, halving down to 1 x 1.
    """

    texels: jax.Array
    sizes: tuple[tuple[int, int], ...] = static_field()

    @property
    def shape(self) -> tuple[int, int]:
        """Level 0's ``(height, width)``."""
        return self.sizes[0]

    @property
    def offsets(self) -> tuple[int, ...]:
        """Each level's first row in :attr:`texels`."""
        return tuple(int(v) for v in np.cumsum([0] + [h * w for h, w in self.sizes[:-1]]))

    def level(self, k: int) -> jax.Array:
        """Level ``k`` as an image (h, w, C)."""
        h, w = self.sizes[k]
        o = self.offsets[k]
        return self.texels[o : o + h * w].reshape(h, w, -1)


def _halve(image: jax.Array) -> jax.Array:
    """The next mip level: each texel the mean of the 2x2 (or, on an odd side, 2x1) below it.

    An odd side keeps its last row or column whole (``(n + 1) // 2`` texels), averaged with
    itself, so every level covers the same [0, 1] square.
    """
    h, w = image.shape[:2]
    if h % 2:
        image = jnp.concatenate([image, image[-1:]], axis=0)
    if w % 2:
        image = jnp.concatenate([image, image[:, -1:]], axis=1)
    h2, w2 = image.shape[0] // 2, image.shape[1] // 2
    return image.reshape(h2, 2, w2, 2, -1).mean(axis=(1, 3))


def mip_pyramid(image, levels: int | None = None) -> MipTexture:
    """The mip levels of an image (2x2 box filter), packed for :func:`texture`.

    Args:
        image: (H, W, C) or (H, W) texture, float in [0, 1] (uint8 is scaled by 1/255).
        levels: how many levels; default down to 1 x 1 (``1 + ceil(log2(max(H, W)))``).

    Returns:
        :class:`MipTexture`; differentiable with respect to ``image``.

    Raises:
        ValueError: ``image`` is not 2-D or 3-D, or empty; ``levels`` < 1.
    """
    check_finite("image", image, "mip_pyramid")
    img = jnp.asarray(image)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"image must have shape (H, W, C) or (H, W), got {np.shape(image)}")
    if img.dtype == jnp.uint8:
        img = img.astype(jnp.float32) / 255.0
    img = img.astype(jnp.float32)
    full = 1 + math.ceil(math.log2(max(img.shape[0], img.shape[1])))
    levels = full if levels is None else min(check_int("levels", levels, low=1), full)
    out = [img]
    while len(out) < levels:
        out.append(_halve(out[-1]))
    sizes = tuple((int(a.shape[0]), int(a.shape[1])) for a in out)
    flat = jnp.concatenate([a.reshape(-1, a.shape[-1]) for a in out])
    return MipTexture(flat, sizes)


def _wrap_index(i: jax.Array, n, wrap: str) -> jax.Array:
    if wrap == "repeat":
        return jnp.mod(i, n)
    return jnp.clip(i, 0, n - 1)


def _bilinear(tex: MipTexture, uv: jax.Array, k: jax.Array, wrap: str) -> jax.Array:
    """Bilinear lookups (..., C) at ``uv`` (..., 2) in levels ``k`` (...) (any per lookup)."""
    sizes = np.asarray(tex.sizes, np.int32)
    h = jnp.asarray(sizes[:, 0])[k]
    w = jnp.asarray(sizes[:, 1])[k]
    off = jnp.asarray(np.asarray(tex.offsets, np.int32))[k]
    x = uv[..., 0] * w.astype(jnp.float32) - 0.5
    y = uv[..., 1] * h.astype(jnp.float32) - 0.5
    x0, y0 = jnp.floor(x), jnp.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    i0, j0 = x0.astype(jnp.int32), y0.astype(jnp.int32)

    def at(i, j):
        row = _wrap_index(j, h, wrap) * w + _wrap_index(i, w, wrap)
        return tex.texels[off + row]

    top = at(i0, j0) * (1 - fx) + at(i0 + 1, j0) * fx
    bottom = at(i0, j0 + 1) * (1 - fx) + at(i0 + 1, j0 + 1) * fx
    return top * (1 - fy) + bottom * fy


def sample_bilinear(tex: MipTexture, uv, *, level: int = 0, wrap: str = "repeat") -> jax.Array:
    """Bilinear lookups (..., C) in one mip level at ``uv`` (..., 2) (no mip-mapping)."""
    _check_wrap(wrap)
    level = check_int("level", level, low=0, high=len(tex.sizes) - 1)
    uv = jnp.asarray(uv, jnp.float32)
    return _bilinear(tex, uv, jnp.full(uv.shape[:-1], level, jnp.int32), wrap)


def texture(tex: MipTexture, uv, footprint=None, *, wrap: str = "repeat") -> jax.Array:
    """Trilinear texture lookups (..., C) at ``uv`` (..., 2).

    The level of detail is ``log2`` of the footprint in level-0 texels (the larger of its
    horizontal and vertical extents), clamped to the pyramid: 0 where a pixel covers a
    texel or less (magnified: bilinear in level 0), and between levels ``floor`` and
    ``floor + 1`` the two bilinear lookups are blended linearly.

    Args:
        tex: :func:`mip_pyramid` of the texture.
        uv: (..., 2) texture coordinates, (0, 0) the image's top-left corner.
        footprint: (..., 2) the UV extent of a pixel, ``(du, dv)`` (from
            :func:`uv_footprint`); None reads level 0 bilinearly.
        wrap: ``"repeat"`` (glTF's default) or ``"clamp"`` outside [0, 1].

    Returns:
        (..., C) float32; differentiable with respect to ``tex`` and ``uv``.
    """
    _check_wrap(wrap)
    check_finite("uv", uv, "texture")  # a NaN UV would read an arbitrary texel
    uv = jnp.asarray(uv, jnp.float32)
    if uv.shape[-1:] != (2,):
        raise ValueError(f"uv must have shape (..., 2), got {uv.shape}")
    require_finite("uv", uv, "texture")
    require_finite("tex.texels", tex.texels, "texture")
    return _texture(tex, uv, footprint, wrap=wrap)


def _texture_of(tex: MipTexture, uv, footprint, wrap: str) -> jax.Array:
    """:func:`texture` of checked arguments."""
    if footprint is None:
        return _bilinear(tex, uv, jnp.zeros(uv.shape[:-1], jnp.int32), wrap)
    fp = jax.lax.stop_gradient(jnp.abs(jnp.asarray(footprint, jnp.float32)))
    h0, w0 = tex.sizes[0]
    texels = jnp.maximum(fp[..., 0] * w0, fp[..., 1] * h0)
    top = len(tex.sizes) - 1
    lod = jnp.clip(jnp.log2(jnp.maximum(texels, 1e-30)), 0.0, float(top))
    k0 = jnp.floor(lod).astype(jnp.int32)
    k1 = jnp.minimum(k0 + 1, top)
    t = (lod - k0.astype(jnp.float32))[..., None]
    return _bilinear(tex, uv, k0, wrap) * (1 - t) + _bilinear(tex, uv, k1, wrap) * t


_texture = compiled_when_eager(_texture_of, static_argnames=("wrap",))


def uv_footprint(uv_image, tri_id) -> jax.Array:
    """Each pixel's UV extent (H, W, 2) from its neighbours on the same triangle.

    The change of the interpolated UVs to the next pixel along x and along y (the
    previous where the next is on another triangle or off the frame, 0 where both are),
    the larger of the two per coordinate: the derivatives a GPU takes over a 2x2 quad.

    Args:
        uv_image: (H, W, 2) interpolated UVs (``rasterize``'s colour of UV attributes).
        tri_id: (H, W) int32 triangle per pixel, -1 where empty.
    """
    uv = jax.lax.stop_gradient(jnp.asarray(uv_image, jnp.float32))
    tid = jnp.asarray(tri_id)

    def along(axis: int) -> jax.Array:
        n = uv.shape[axis]
        nxt = jnp.roll(uv, -1, axis) - uv
        prv = uv - jnp.roll(uv, 1, axis)
        idx = jnp.arange(n).reshape((-1, 1) if axis == 0 else (1, -1))
        same_next = (jnp.roll(tid, -1, axis) == tid) & (idx < n - 1)
        same_prev = (jnp.roll(tid, 1, axis) == tid) & (idx > 0)
        d = jnp.where(same_next[..., None], nxt, jnp.where(same_prev[..., None], prv, 0.0))
        return jnp.abs(d)

    return jnp.maximum(along(0), along(1))


def _check_wrap(wrap: str) -> None:
    if wrap not in WRAPS:
        raise ValueError(f"wrap must be one of {WRAPS}, got {wrap!r}")
