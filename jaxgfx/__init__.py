"""jaxgfx: game-engine visualization in JAX (thesis chapters 2-5).

Engine: one camera for every pass (``camera``), a JAX z-buffer rasterizer (``raster``),
depth compositing (``compose``), I/O (``io``), scenes (``scene``) and sharded, resumable
sweeps (``sweep``).  Chapter modules: ``terrain`` (ch. 3, Clip-Box volumetric terrain),
``voxels``/``raycast``/``post`` (ch. 4, RLE voxels and the per-plane ray caster), ``skin``
and ``fit`` (ch. 5, spline skinning and deformation styles), ``gltf`` (skinned glTF assets).
Every public name is re-exported here; the modules stay importable as ``jaxgfx.<module>``.
"""

__version__ = "0.1.0"

from jaxgfx import (  # noqa: E402
    camera,
    compose,
    fit,
    gltf,
    io,
    post,
    raster,
    raycast,
    scene,
    skin,
    terrain,
)
from jaxgfx.camera import Camera as Camera
from jaxgfx.camera import camera_basis as camera_basis
from jaxgfx.camera import camera_from_degrees as camera_from_degrees
from jaxgfx.camera import camera_matrix as camera_matrix
from jaxgfx.camera import camera_to_screen as camera_to_screen
from jaxgfx.camera import focal_length as focal_length
from jaxgfx.camera import focal_lengths as focal_lengths
from jaxgfx.camera import look_at as look_at
from jaxgfx.camera import orbit_cameras as orbit_cameras
from jaxgfx.camera import pixel_rays as pixel_rays
from jaxgfx.camera import project as project
from jaxgfx.camera import projection_matrix as projection_matrix
from jaxgfx.camera import screen_to_camera as screen_to_camera
from jaxgfx.camera import stack_cameras as stack_cameras
from jaxgfx.camera import supersampled as supersampled
from jaxgfx.camera import validate_camera as validate_camera
from jaxgfx.camera import view_matrix as view_matrix
from jaxgfx.camera import world_to_camera as world_to_camera
from jaxgfx.compose import Frame as Frame
from jaxgfx.compose import background as background
from jaxgfx.compose import composite as composite
from jaxgfx.compose import composite_pair as composite_pair
from jaxgfx.compose import depth_image as depth_image
from jaxgfx.compose import fog as fog
from jaxgfx.compose import lambert as lambert
from jaxgfx.compose import to_uint8 as to_uint8
from jaxgfx.fit import FitResult as FitResult
from jaxgfx.fit import fit_style as fit_style
from jaxgfx.fit import params_to_style as params_to_style
from jaxgfx.fit import smoothness_penalty as smoothness_penalty
from jaxgfx.fit import style_loss as style_loss
from jaxgfx.fit import style_to_params as style_to_params
from jaxgfx.gltf import GltfSkin as GltfSkin
from jaxgfx.gltf import joint_globals as joint_globals
from jaxgfx.gltf import joint_matrices as joint_matrices
from jaxgfx.gltf import load_gltf_skin as load_gltf_skin
from jaxgfx.gltf import sample_animation as sample_animation
from jaxgfx.gltf import trs_matrix as trs_matrix
from jaxgfx.io import atomic_write as atomic_write
from jaxgfx.io import load_mesh as load_mesh
from jaxgfx.io import mesh_arrays as mesh_arrays
from jaxgfx.io import save_json as save_json
from jaxgfx.io import save_mesh as save_mesh
from jaxgfx.io import save_npy as save_npy
from jaxgfx.io import save_png as save_png
from jaxgfx.post import ambient_occlusion as ambient_occlusion
from jaxgfx.post import antialias as antialias
from jaxgfx.post import screen_space_normals as screen_space_normals
from jaxgfx.post import shade as shade
from jaxgfx.post import smooth as smooth
from jaxgfx.raster import ClippedTriangles as ClippedTriangles
from jaxgfx.raster import RasterOutput as RasterOutput
from jaxgfx.raster import TriangleSetup as TriangleSetup
from jaxgfx.raster import clip_near as clip_near
from jaxgfx.raster import corners_soa as corners_soa
from jaxgfx.raster import coverage_count as coverage_count
from jaxgfx.raster import face_normals as face_normals
from jaxgfx.raster import interpolate as interpolate
from jaxgfx.raster import rasterize as rasterize
from jaxgfx.raster import resolve as resolve
from jaxgfx.raster import triangle_setup as triangle_setup
from jaxgfx.raster import validate_mesh as validate_mesh
from jaxgfx.raster import vertex_normals as vertex_normals
from jaxgfx.raster import visibility as visibility
from jaxgfx.raycast import DRAW_BITS as DRAW_BITS
from jaxgfx.raycast import MAX_DRAW as MAX_DRAW
from jaxgfx.raycast import MAX_SKIP as MAX_SKIP
from jaxgfx.raycast import MAX_VOXELS as MAX_VOXELS
from jaxgfx.raycast import SKIP_BITS as SKIP_BITS
from jaxgfx.raycast import PlaneParams as PlaneParams
from jaxgfx.raycast import RenderOutput as RenderOutput
from jaxgfx.raycast import RenderSettings as RenderSettings
from jaxgfx.raycast import RLEVolume as RLEVolume
from jaxgfx.raycast import Segments as Segments
from jaxgfx.raycast import Voxels as Voxels
from jaxgfx.raycast import as_jax as as_jax
from jaxgfx.raycast import check_camera_outside as check_camera_outside
from jaxgfx.raycast import crop_voxels as crop_voxels
from jaxgfx.raycast import dda_ray_3d as dda_ray_3d
from jaxgfx.raycast import decode_rle as decode_rle
from jaxgfx.raycast import default_max_steps as default_max_steps
from jaxgfx.raycast import default_num_planes as default_num_planes
from jaxgfx.raycast import dense_to_voxels as dense_to_voxels
from jaxgfx.raycast import downsample_voxels as downsample_voxels
from jaxgfx.raycast import empty_space_distance as empty_space_distance
from jaxgfx.raycast import encode_rle as encode_rle
from jaxgfx.raycast import load_kv6 as load_kv6
from jaxgfx.raycast import load_scene as load_scene
from jaxgfx.raycast import load_volume as load_volume
from jaxgfx.raycast import load_vxl as load_vxl
from jaxgfx.raycast import make_voxels as make_voxels
from jaxgfx.raycast import place_instances as place_instances
from jaxgfx.raycast import plane_extent as plane_extent
from jaxgfx.raycast import plane_parameters as plane_parameters
from jaxgfx.raycast import procedural_tree as procedural_tree
from jaxgfx.raycast import ray_buffer_coords as ray_buffer_coords
from jaxgfx.raycast import reference_render as reference_render
from jaxgfx.raycast import refine_hits as refine_hits
from jaxgfx.raycast import refine_pixel as refine_pixel
from jaxgfx.raycast import render_rle as render_rle
from jaxgfx.raycast import rle_stats as rle_stats
from jaxgfx.raycast import save_scene as save_scene
from jaxgfx.raycast import screen_segments as screen_segments
from jaxgfx.raycast import surface_mask as surface_mask
from jaxgfx.raycast import surface_voxels as surface_voxels
from jaxgfx.raycast import traverse_plane as traverse_plane
from jaxgfx.raycast import traverse_planes as traverse_planes
from jaxgfx.raycast import vanishing_point as vanishing_point
from jaxgfx.raycast import volume_to_voxels as volume_to_voxels
from jaxgfx.raycast import voxelize_mesh as voxelize_mesh
from jaxgfx.raycast import voxels_to_dense as voxels_to_dense
from jaxgfx.raycast import warp_ray_buffer as warp_ray_buffer
from jaxgfx.scene import CharacterPass as CharacterPass
from jaxgfx.scene import Demo as Demo
from jaxgfx.scene import MeshPass as MeshPass
from jaxgfx.scene import VoxelPass as VoxelPass
from jaxgfx.scene import build_demo as build_demo
from jaxgfx.scene import character_pose as character_pose
from jaxgfx.scene import demo_character_pass as demo_character_pass
from jaxgfx.scene import demo_forest as demo_forest
from jaxgfx.scene import demo_meshes as demo_meshes
from jaxgfx.scene import demo_terrain as demo_terrain
from jaxgfx.scene import grid_faces as grid_faces
from jaxgfx.scene import merge_mesh_passes as merge_mesh_passes
from jaxgfx.scene import mesh_pass as mesh_pass
from jaxgfx.scene import render_character as render_character
from jaxgfx.scene import render_frame as render_frame
from jaxgfx.scene import render_mesh_pass as render_mesh_pass
from jaxgfx.scene import render_voxel_pass as render_voxel_pass
from jaxgfx.scene import terrain_mesh_pass as terrain_mesh_pass
from jaxgfx.skin import SampledBinding as SampledBinding
from jaxgfx.skin import SkinBinding as SkinBinding
from jaxgfx.skin import SplinePose as SplinePose
from jaxgfx.skin import SplineRig as SplineRig
from jaxgfx.skin import Style as Style
from jaxgfx.skin import apply_style as apply_style
from jaxgfx.skin import attach_children as attach_children
from jaxgfx.skin import axis_angle_to_matrix as axis_angle_to_matrix
from jaxgfx.skin import bend_angle as bend_angle
from jaxgfx.skin import bezier_point as bezier_point
from jaxgfx.skin import bezier_tangent as bezier_tangent
from jaxgfx.skin import bind_mesh as bind_mesh
from jaxgfx.skin import bind_pose as bind_pose
from jaxgfx.skin import bind_vertex as bind_vertex
from jaxgfx.skin import bone_transforms as bone_transforms
from jaxgfx.skin import bone_weights_from_binding as bone_weights_from_binding
from jaxgfx.skin import brute_force_binding as brute_force_binding
from jaxgfx.skin import demo_character as demo_character
from jaxgfx.skin import dqs_vertex as dqs_vertex
from jaxgfx.skin import dual_quaternion_skinning as dual_quaternion_skinning
from jaxgfx.skin import dual_quaternions as dual_quaternions
from jaxgfx.skin import forward_kinematics as forward_kinematics
from jaxgfx.skin import frame_inverse as frame_inverse
from jaxgfx.skin import identity_style as identity_style
from jaxgfx.skin import lbs_vertex as lbs_vertex
from jaxgfx.skin import limb_mesh as limb_mesh
from jaxgfx.skin import linear_blend_skinning as linear_blend_skinning
from jaxgfx.skin import make_rig as make_rig
from jaxgfx.skin import make_style as make_style
from jaxgfx.skin import matrix_to_quaternion as matrix_to_quaternion
from jaxgfx.skin import muscle_style as muscle_style
from jaxgfx.skin import prepare_sampled as prepare_sampled
from jaxgfx.skin import radial_scale as radial_scale
from jaxgfx.skin import rect_scale as rect_scale
from jaxgfx.skin import sample_curve as sample_curve
from jaxgfx.skin import sample_spline_frames as sample_spline_frames
from jaxgfx.skin import sample_texture as sample_texture
from jaxgfx.skin import skin_exact as skin_exact
from jaxgfx.skin import skin_sampled as skin_sampled
from jaxgfx.skin import skin_vertex_exact as skin_vertex_exact
from jaxgfx.skin import skin_vertex_sampled as skin_vertex_sampled
from jaxgfx.skin import spline_frame as spline_frame
from jaxgfx.skin import spline_frames as spline_frames
from jaxgfx.skin import spline_point as spline_point
from jaxgfx.skin import spline_tangent as spline_tangent
from jaxgfx.skin import start_normal as start_normal
from jaxgfx.skin import style_offset_sampled as style_offset_sampled
from jaxgfx.skin import validate_pose as validate_pose
from jaxgfx.sweep import batch_size as batch_size
from jaxgfx.sweep import chunk_path as chunk_path
from jaxgfx.sweep import device_mesh as device_mesh
from jaxgfx.sweep import load_sweep as load_sweep
from jaxgfx.sweep import sharded_renderer as sharded_renderer
from jaxgfx.sweep import sweep as sweep
from jaxgfx.terrain import PRIMITIVE_BOX as PRIMITIVE_BOX
from jaxgfx.terrain import PRIMITIVE_CYLINDER as PRIMITIVE_CYLINDER
from jaxgfx.terrain import PRIMITIVE_SPHERE as PRIMITIVE_SPHERE
from jaxgfx.terrain import ClipBox as ClipBox
from jaxgfx.terrain import ClipBoxMesh as ClipBoxMesh
from jaxgfx.terrain import ClipBoxPipeline as ClipBoxPipeline
from jaxgfx.terrain import CSGTerrain as CSGTerrain
from jaxgfx.terrain import FunctionTerrain as FunctionTerrain
from jaxgfx.terrain import GeometryWorker as GeometryWorker
from jaxgfx.terrain import HeightmapTerrain as HeightmapTerrain
from jaxgfx.terrain import NestedClipBoxes as NestedClipBoxes
from jaxgfx.terrain import SawTerrain as SawTerrain
from jaxgfx.terrain import SinTerrain as SinTerrain
from jaxgfx.terrain import SubdividedMesh as SubdividedMesh
from jaxgfx.terrain import VolumeTerrain as VolumeTerrain
from jaxgfx.terrain import XorTerrain as XorTerrain
from jaxgfx.terrain import as_terrain as as_terrain
from jaxgfx.terrain import check_terrain as check_terrain
from jaxgfx.terrain import clipbox_origin as clipbox_origin
from jaxgfx.terrain import csg_terrain as csg_terrain
from jaxgfx.terrain import heightmap_terrain as heightmap_terrain
from jaxgfx.terrain import int_sin as int_sin
from jaxgfx.terrain import level_arrays as level_arrays
from jaxgfx.terrain import level_views as level_views
from jaxgfx.terrain import load_heightmap as load_heightmap
from jaxgfx.terrain import mesh_normals as mesh_normals
from jaxgfx.terrain import mesh_to_trimesh as mesh_to_trimesh
from jaxgfx.terrain import nested_origins as nested_origins
from jaxgfx.terrain import pattern_filter as pattern_filter
from jaxgfx.terrain import random_csg_terrain as random_csg_terrain
from jaxgfx.terrain import render_levels as render_levels
from jaxgfx.terrain import reused_fraction as reused_fraction
from jaxgfx.terrain import sample_clipbox as sample_clipbox
from jaxgfx.terrain import sample_terrain as sample_terrain
from jaxgfx.terrain import shift_clipbox as shift_clipbox
from jaxgfx.terrain import slab_thickness as slab_thickness
from jaxgfx.terrain import smooth_mesh as smooth_mesh
from jaxgfx.terrain import subdivide_mesh as subdivide_mesh
from jaxgfx.terrain import visible_faces as visible_faces
from jaxgfx.terrain import volume_terrain as volume_terrain
from jaxgfx.terrain import voxels_to_mesh as voxels_to_mesh
from jaxgfx.terrain import weld_seam as weld_seam
