"""Differentiable silhouettes: analytic antialiasing of a rasterized image.

:func:`analytic_antialias` blends pixel pairs across silhouette edges by where the edge
crosses them (Laine et al. 2020, Sec. 3.4), so the image has gradients with respect to the
vertices and the camera; :func:`silhouette_edges` finds a mesh's edge topology once.
"""

from __future__ import annotations

from jaxgfx._src.silhouette import analytic_antialias as analytic_antialias
from jaxgfx._src.silhouette import silhouette_edges as silhouette_edges

__all__ = [
    "silhouette_edges",
    "analytic_antialias",
]
