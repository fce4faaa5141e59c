"""File input and output: meshes through trimesh, PNG through imageio, every write atomic."""

from __future__ import annotations

from jaxgfx._src.io import atomic_write as atomic_write
from jaxgfx._src.io import load_mesh as load_mesh
from jaxgfx._src.io import mesh_arrays as mesh_arrays
from jaxgfx._src.io import mesh_texture as mesh_texture
from jaxgfx._src.io import save_json as save_json
from jaxgfx._src.io import save_mesh as save_mesh
from jaxgfx._src.io import save_npy as save_npy
from jaxgfx._src.io import save_png as save_png
from jaxgfx._src.io import up_rotation as up_rotation

__all__ = [
    "atomic_write",
    "load_mesh",
    "up_rotation",
    "mesh_arrays",
    "mesh_texture",
    "save_png",
    "save_npy",
    "save_json",
    "save_mesh",
]
