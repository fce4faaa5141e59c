"""Z-buffer triangle rasterizer in pure JAX (thesis 2.3, the polygon pass).

:func:`rasterize` draws one mesh for one :class:`~jaxgfx.camera.Camera` into colour,
depth, face ids and perspective-correct barycentrics; batch cameras or posed vertices with
``jax.vmap``.  Rasterize UVs as attributes and read a texture there with
:func:`texture` (mip-mapped, filtered, differentiable in the texels and the UVs).  Its
visibility is piecewise constant in the vertices; for images with
gradients at silhouettes use :func:`jaxgfx.silhouette.analytic_antialias`.  The stages
(near-plane clipping, triangle setup, the tiled z-buffer) and their measurements are in
the docs' design notes.
"""

from __future__ import annotations

from jaxgfx._src.raster import RasterOutput as RasterOutput
from jaxgfx._src.raster import coverage_count as coverage_count
from jaxgfx._src.raster import interpolate as interpolate
from jaxgfx._src.raster import rasterize as rasterize
from jaxgfx._src.raster import resolve as resolve
from jaxgfx._src.raster import validate_mesh as validate_mesh
from jaxgfx._src.raster import vertex_normals as vertex_normals
from jaxgfx._src.texture import MipTexture as MipTexture
from jaxgfx._src.texture import mip_pyramid as mip_pyramid
from jaxgfx._src.texture import sample_bilinear as sample_bilinear
from jaxgfx._src.texture import texture as texture
from jaxgfx._src.texture import uv_footprint as uv_footprint

__all__ = [
    "RasterOutput",
    "rasterize",
    "interpolate",
    "resolve",
    "coverage_count",
    "vertex_normals",
    "validate_mesh",
    "MipTexture",
    "mip_pyramid",
    "texture",
    "sample_bilinear",
    "uv_footprint",
]
