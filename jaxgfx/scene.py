"""Render passes joined into one frame with the shared camera (thesis 2.3-2.4).

A polygon pass (:class:`MeshPass`), a voxel pass (:class:`VoxelPass`) and any function that
returns a :class:`~jaxgfx.compose.Frame` are drawn with one camera and merged through the
depth buffer by :func:`render_frame`.
"""

from __future__ import annotations

from jaxgfx._src.scene import MeshPass as MeshPass
from jaxgfx._src.scene import VoxelPass as VoxelPass
from jaxgfx._src.scene import grid_faces as grid_faces
from jaxgfx._src.scene import merge_mesh_passes as merge_mesh_passes
from jaxgfx._src.scene import mesh_pass as mesh_pass
from jaxgfx._src.scene import render_frame as render_frame
from jaxgfx._src.scene import render_mesh_pass as render_mesh_pass
from jaxgfx._src.scene import render_voxel_pass as render_voxel_pass

__all__ = [
    "MeshPass",
    "mesh_pass",
    "merge_mesh_passes",
    "render_mesh_pass",
    "render_frame",
    "grid_faces",
    "VoxelPass",
    "render_voxel_pass",
]
