"""Screen-space post-processing of voxel frames (thesis 4.5.6).

Normals from the depth image (Eq. 4.7), ambient occlusion, smoothing and the thesis's
anti-aliasing (a frame rendered on a finer grid and averaged back).
"""

from __future__ import annotations

from jaxgfx._src.post import ambient_occlusion as ambient_occlusion
from jaxgfx._src.post import antialias as antialias
from jaxgfx._src.post import screen_space_normals as screen_space_normals
from jaxgfx._src.post import shade as shade
from jaxgfx._src.post import shade_voxels as shade_voxels
from jaxgfx._src.post import smooth as smooth

__all__ = [
    "antialias",
    "smooth",
    "screen_space_normals",
    "ambient_occlusion",
    "shade",
    "shade_voxels",
]
