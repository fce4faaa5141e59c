"""jaxgfx: game-engine visualization in JAX.

Shared engine: one camera for every pass, a JAX z-buffer rasterizer,
depth compositing, I/O and sharded batch sweeps.
"""

__version__ = "0.1.0"

from jaxgfx.camera import Camera as Camera
from jaxgfx.camera import camera_basis as camera_basis
from jaxgfx.camera import camera_from_degrees as camera_from_degrees
from jaxgfx.camera import camera_matrix as camera_matrix
from jaxgfx.camera import focal_length as focal_length
from jaxgfx.camera import look_at as look_at
from jaxgfx.camera import orbit_cameras as orbit_cameras
from jaxgfx.camera import pixel_rays as pixel_rays
from jaxgfx.camera import project as project
from jaxgfx.camera import projection_matrix as projection_matrix
from jaxgfx.camera import stack_cameras as stack_cameras
from jaxgfx.camera import view_matrix as view_matrix
from jaxgfx.camera import world_to_camera as world_to_camera
from jaxgfx.compose import Frame as Frame
from jaxgfx.compose import background as background
from jaxgfx.compose import composite as composite
from jaxgfx.compose import depth_image as depth_image
from jaxgfx.compose import fog as fog
from jaxgfx.compose import lambert as lambert
from jaxgfx.io import load_mesh as load_mesh
from jaxgfx.io import mesh_arrays as mesh_arrays
from jaxgfx.io import save_mesh as save_mesh
from jaxgfx.io import save_png as save_png
from jaxgfx.raster import RasterOutput as RasterOutput
from jaxgfx.raster import coverage_count as coverage_count
from jaxgfx.raster import interpolate as interpolate
from jaxgfx.raster import rasterize as rasterize
from jaxgfx.raster import validate_mesh as validate_mesh
from jaxgfx.raster import vertex_normals as vertex_normals
from jaxgfx.scene import MeshPass as MeshPass
from jaxgfx.scene import mesh_pass as mesh_pass
from jaxgfx.scene import render_frame as render_frame
from jaxgfx.scene import render_mesh_pass as render_mesh_pass
from jaxgfx.sweep import load_sweep as load_sweep
from jaxgfx.sweep import sharded_renderer as sharded_renderer
from jaxgfx.sweep import sweep as sweep
