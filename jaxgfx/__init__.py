"""jaxgfx: game-engine visualization in JAX, after one thesis (chapters 2-5).

The names below are the ones a user needs; each is documented where it is defined.
Every chapter keeps all of its public functions in its face module, one import away:

- ``jaxgfx.terrain`` (ch. 3): terrain functions, Clip-Boxes, meshing, pipeline, worker.
- ``jaxgfx.raycast`` (ch. 4): voxelization, volume and Voxlap import, trees, RLE encoding,
  the per-plane ray caster and its reference DDA.
- ``jaxgfx.skin`` (ch. 5): spline rigs, binding, deformation styles, spline/LBS/DQS
  skinning, style fitting, glTF rigs.

The engine (ch. 2) is in ``jaxgfx.camera`` (one camera for every pass), ``jaxgfx.raster``
(the z-buffer rasterizer), ``jaxgfx.compose`` (depth compositing, sky, fog, lighting),
``jaxgfx.post`` (screen-space normals, AO, anti-aliasing), ``jaxgfx.silhouette``
(differentiable silhouettes: analytic antialiasing), ``jaxgfx.io``, ``jaxgfx.scene``
(passes joined into one frame) and ``jaxgfx.sweep`` (batched, sharded, resumable sweeps;
a module: its entry points are :func:`~jaxgfx.sweep.run_sweep` and
:func:`~jaxgfx.sweep.load_sweep`); ``jaxgfx.checks`` checks the values of traced arguments
too (:func:`~jaxgfx.checks.checked`).  The implementation modules are private: every public
name is in one of these modules.
"""

__version__ = "0.1.0"

from jaxgfx import (
    camera,
    checks,
    compose,
    io,
    post,
    raster,
    raycast,
    scene,
    silhouette,
    skin,
    sweep,
    terrain,
)
from jaxgfx._src.hostmem import keep_freed_memory
from jaxgfx.camera import (
    Camera,
    camera_from_degrees,
    look_at,
    orbit_cameras,
    pixel_rays,
    project,
    stack_cameras,
    supersampled,
)
from jaxgfx.checks import checked
from jaxgfx.compose import Frame, background, composite, depth_image, fog, lambert, to_uint8
from jaxgfx.io import atomic_write, load_mesh, mesh_arrays, save_mesh, save_npy, save_png
from jaxgfx.post import ambient_occlusion, antialias, screen_space_normals, shade
from jaxgfx.raster import RasterOutput, interpolate, rasterize, vertex_normals
from jaxgfx.raycast import (
    RenderSettings,
    RLEVolume,
    Voxels,
    decode_rle,
    encode_rle,
    load_kv6,
    load_scene,
    load_volume,
    load_vxl,
    place_instances,
    procedural_tree,
    reference_render,
    render_rle,
    save_scene,
    volume_to_voxels,
    voxelize_mesh,
)
from jaxgfx.scene import MeshPass, mesh_pass, render_frame, render_mesh_pass
from jaxgfx.showcase import build_demo
from jaxgfx.silhouette import analytic_antialias
from jaxgfx.skin import (
    SplinePose,
    SplineRig,
    Style,
    axis_angle_to_matrix,
    bind_mesh,
    bone_transforms,
    bone_weights_from_binding,
    dual_quaternion_skinning,
    fit_style,
    forward_kinematics,
    identity_style,
    linear_blend_skinning,
    load_gltf_skin,
    make_rig,
    make_style,
    muscle_style,
    prepare_sampled,
    skin_exact,
    skin_sampled,
)
from jaxgfx.sweep import load_sweep, run_sweep, sharded_renderer, sharded_vmap
from jaxgfx.terrain import (
    ClipBoxPipeline,
    CSGTerrain,
    GeometryWorker,
    SawTerrain,
    SinTerrain,
    XorTerrain,
    csg_terrain,
    heightmap_terrain,
    load_heightmap,
    mesh_to_trimesh,
    random_csg_terrain,
    render_levels,
    volume_terrain,
    voxels_to_mesh,
)

__all__ = [
    # camera: one camera for every pass
    "Camera",
    "camera_from_degrees",
    "look_at",
    "orbit_cameras",
    "stack_cameras",
    "supersampled",
    "project",
    "pixel_rays",
    # rasterizer
    "rasterize",
    "analytic_antialias",
    "RasterOutput",
    "interpolate",
    "vertex_normals",
    # compositing and post-processing
    "Frame",
    "background",
    "composite",
    "fog",
    "lambert",
    "depth_image",
    "to_uint8",
    "screen_space_normals",
    "ambient_occlusion",
    "shade",
    "antialias",
    # files
    "load_mesh",
    "mesh_arrays",
    "save_png",
    "save_npy",
    "save_mesh",
    "atomic_write",
    # scenes and sweeps
    "MeshPass",
    "mesh_pass",
    "render_mesh_pass",
    "render_frame",
    "build_demo",
    "run_sweep",
    "load_sweep",
    "sharded_renderer",
    "sharded_vmap",
    "keep_freed_memory",
    "checked",
    # ch. 3 terrain
    "XorTerrain",
    "SawTerrain",
    "SinTerrain",
    "CSGTerrain",
    "csg_terrain",
    "random_csg_terrain",
    "load_heightmap",
    "heightmap_terrain",
    "volume_terrain",
    "ClipBoxPipeline",
    "GeometryWorker",
    "voxels_to_mesh",
    "render_levels",
    "mesh_to_trimesh",
    # ch. 4 voxels and the ray caster
    "Voxels",
    "voxelize_mesh",
    "load_volume",
    "volume_to_voxels",
    "load_vxl",
    "load_kv6",
    "procedural_tree",
    "save_scene",
    "load_scene",
    "RLEVolume",
    "encode_rle",
    "decode_rle",
    "place_instances",
    "RenderSettings",
    "render_rle",
    "reference_render",
    # ch. 5 skinning
    "SplineRig",
    "SplinePose",
    "Style",
    "make_rig",
    "forward_kinematics",
    "axis_angle_to_matrix",
    "bind_mesh",
    "make_style",
    "identity_style",
    "muscle_style",
    "skin_exact",
    "prepare_sampled",
    "skin_sampled",
    "bone_transforms",
    "bone_weights_from_binding",
    "linear_blend_skinning",
    "dual_quaternion_skinning",
    "fit_style",
    "load_gltf_skin",
    # chapter and engine modules
    "camera",
    "checks",
    "raster",
    "compose",
    "post",
    "silhouette",
    "io",
    "scene",
    "sweep",
    "terrain",
    "raycast",
    "skin",
]
