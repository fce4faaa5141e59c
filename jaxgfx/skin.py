"""Chapter 5: spline skinning, deformation styles and their baselines (the chapter's face).

Every function is written for one item (one spline, one vertex) and batched with ``jax.vmap``
by the caller.  Where each thesis section lives (with the implementation module behind it):

* 5.4 Splines, the rig and its hierarchy (Fig. 5.16) -- ``rig``: :class:`SplineRig`,
  :class:`SplinePose`, :func:`make_rig`, :func:`validate_pose`, :func:`forward_kinematics`.
* 5.4.1-5.4.2 Stiffness splines and frames (Eq. 5.1-5.4) -- ``spline``: :func:`bezier_point`,
  :func:`spline_point`, :func:`spline_tangent`, :func:`spline_frame` (the frame
  ``B = [b_N | b_B | b_T | b_O]`` as a (3, 4) matrix), :func:`spline_frames`; the frame
  conventions (reference normal, twist, handedness) are in that module's docstring.
* 5.4.3 Spline binding (Eq. 5.5-5.6) -- ``binding``: :func:`bind_vertex`, :func:`bind_mesh`.
* 5.6 Deformation styles (Eq. 5.8-5.12) -- ``styles``: :class:`Style`, :func:`make_style`,
  :func:`radial_scale`, :func:`rect_scale`, :func:`apply_style`.
* 5.5 / 5.7 Spline skinning with styles (Eq. 5.7, 5.13) -- ``skinning``:
  :func:`skin_vertex_exact`, :func:`skin_exact` (frames per vertex).
* 5.8 Fast computation (passes 1 and 2) -- ``sampled``: :func:`sample_spline_frames`,
  :func:`prepare_sampled`, :func:`skin_vertex_sampled`, :func:`skin_sampled` (pass 2 alone:
  :func:`skin_sampled_tables`; ``subrows=Q`` expands the table to Q sub-rows per sample in pass 1
  so that pass 2 runs LBS's kernel, with ``u`` rounded to ``1/Q`` of a sample step).
* 5.9 Baselines on the same skeleton -- ``baselines``: :func:`bone_transforms`,
  :func:`linear_blend_skinning` (SSD) and :func:`dual_quaternion_skinning` (Kavan et al.).
* The mesh kernels behind :func:`linear_blend_skinning` and :func:`skin_sampled` -- ``kernels``
  (structure-of-arrays layout XLA:CPU fuses; equal to the per-vertex functions vmapped).  A
  batch of characters or poses on every core: :func:`jaxgfx.sweep.sharded_vmap` with one XLA host
  device per core and ``chunk=8`` (each core loops over 8 poses at a time, so the bone table
  stays in its cache)::

      lbs = sweep.sharded_vmap(skin.linear_blend_skinning, (0, None, None, None, None), chunk=8)
      pos, nrm = lbs(transforms, *lbs.replicate((vertices, normals, joints, weights)))
* Styles fitted by gradient descent instead of painted (5.6 made differentiable) -- ``fit``:
  :func:`fit_style`.
* Styles fitted to depth and silhouette images of posed characters from several cameras
  (skinning -> rasterize -> analytic antialias, batched with vmap) -- ``fit_images``:
  :func:`fit_style_images`, :func:`render_style_images`, :func:`style_image_loss`,
  :func:`welded_silhouette_edges`.
* Skinned glTF characters (JOINTS_0 / WEIGHTS_0, animations) -- ``gltf``:
  :func:`load_gltf_skin`, :func:`sample_animation`, :func:`joint_matrices`; the file's unskinned
  meshes (props) at their node transforms: :func:`load_gltf_meshes`.
* 5.9.3 A bone chain of a glTF character replaced by one spline (fewer control joints) --
  ``chain``: :func:`gltf_spline_chain` (host, once: the spline through three joints' bind origins,
  the binding and weight split), :func:`gltf_pose` (host, per frame: joint matrices, the chain's
  posed points and start rotation at ``time``), :func:`skin_gltf_chain` (jittable: other bones by
  LBS, the chain by spline skinning with an optional :class:`Style`, blended by weight)::

      fox = skin.load_gltf_skin("fox.glb")
      tail = skin.gltf_spline_chain(fox, ("b_Tail01", "b_Tail02", "b_Tail03"), stiffness=3.0)
      pos, nrm = jax.jit(skin.skin_gltf_chain)(tail, skin.gltf_pose(fox, tail, 0.7),
                                               skin.muscle_style())
* The demo arm of the scene, the CLI and the tests -- ``demo``: :func:`demo_arm`,
  :func:`demo_arm_pose`, :func:`demo_character`, :func:`limb_mesh`.
"""

from __future__ import annotations

from jaxgfx._src.skin.baselines import bone_transforms as bone_transforms
from jaxgfx._src.skin.baselines import bone_weights_from_binding as bone_weights_from_binding
from jaxgfx._src.skin.baselines import dqs_vertex as dqs_vertex
from jaxgfx._src.skin.baselines import dual_quaternion_skinning as dual_quaternion_skinning
from jaxgfx._src.skin.baselines import dual_quaternions as dual_quaternions
from jaxgfx._src.skin.baselines import lbs_vertex as lbs_vertex
from jaxgfx._src.skin.baselines import linear_blend_skinning as linear_blend_skinning
from jaxgfx._src.skin.baselines import matrix_to_quaternion as matrix_to_quaternion
from jaxgfx._src.skin.binding import SkinBinding as SkinBinding
from jaxgfx._src.skin.binding import bind_mesh as bind_mesh
from jaxgfx._src.skin.binding import bind_vertex as bind_vertex
from jaxgfx._src.skin.binding import brute_force_binding as brute_force_binding
from jaxgfx._src.skin.chain import TAIL_JOINTS as TAIL_JOINTS
from jaxgfx._src.skin.chain import GltfChainPose as GltfChainPose
from jaxgfx._src.skin.chain import GltfSplineChain as GltfSplineChain
from jaxgfx._src.skin.chain import gltf_pose as gltf_pose
from jaxgfx._src.skin.chain import gltf_spline_chain as gltf_spline_chain
from jaxgfx._src.skin.chain import skin_gltf_chain as skin_gltf_chain
from jaxgfx._src.skin.fit import FitResult as FitResult
from jaxgfx._src.skin.fit import fit_style as fit_style
from jaxgfx._src.skin.fit import params_to_style as params_to_style
from jaxgfx._src.skin.fit import smoothness_penalty as smoothness_penalty
from jaxgfx._src.skin.fit import style_loss as style_loss
from jaxgfx._src.skin.fit import style_to_params as style_to_params
from jaxgfx._src.skin.fit_images import ImageTargets as ImageTargets
from jaxgfx._src.skin.fit_images import fit_style_images as fit_style_images
from jaxgfx._src.skin.fit_images import image_loss as image_loss
from jaxgfx._src.skin.fit_images import render_silhouette_depth as render_silhouette_depth
from jaxgfx._src.skin.fit_images import render_style_images as render_style_images
from jaxgfx._src.skin.fit_images import style_image_loss as style_image_loss
from jaxgfx._src.skin.fit_images import (
    welded_silhouette_edges as welded_silhouette_edges,
)
from jaxgfx._src.skin.gltf import GltfMesh as GltfMesh
from jaxgfx._src.skin.gltf import GltfSkin as GltfSkin
from jaxgfx._src.skin.gltf import joint_globals as joint_globals
from jaxgfx._src.skin.gltf import joint_matrices as joint_matrices
from jaxgfx._src.skin.gltf import load_gltf_meshes as load_gltf_meshes
from jaxgfx._src.skin.gltf import load_gltf_skin as load_gltf_skin
from jaxgfx._src.skin.gltf import sample_animation as sample_animation
from jaxgfx._src.skin.gltf import trs_matrix as trs_matrix
from jaxgfx._src.skin.limb import DemoArm as DemoArm
from jaxgfx._src.skin.limb import demo_arm as demo_arm
from jaxgfx._src.skin.limb import demo_arm_pose as demo_arm_pose
from jaxgfx._src.skin.limb import demo_character as demo_character
from jaxgfx._src.skin.limb import limb_mesh as limb_mesh
from jaxgfx._src.skin.rig import SplinePose as SplinePose
from jaxgfx._src.skin.rig import SplineRig as SplineRig
from jaxgfx._src.skin.rig import attach_children as attach_children
from jaxgfx._src.skin.rig import axis_angle_to_matrix as axis_angle_to_matrix
from jaxgfx._src.skin.rig import bind_pose as bind_pose
from jaxgfx._src.skin.rig import forward_kinematics as forward_kinematics
from jaxgfx._src.skin.rig import make_rig as make_rig
from jaxgfx._src.skin.rig import validate_pose as validate_pose
from jaxgfx._src.skin.sampled import SampledBinding as SampledBinding
from jaxgfx._src.skin.sampled import prepare_sampled as prepare_sampled
from jaxgfx._src.skin.sampled import sample_spline_frames as sample_spline_frames
from jaxgfx._src.skin.sampled import skin_sampled as skin_sampled
from jaxgfx._src.skin.sampled import skin_sampled_tables as skin_sampled_tables
from jaxgfx._src.skin.sampled import skin_vertex_sampled as skin_vertex_sampled
from jaxgfx._src.skin.sampled import style_offset_sampled as style_offset_sampled
from jaxgfx._src.skin.skinning import skin_exact as skin_exact
from jaxgfx._src.skin.skinning import skin_vertex_exact as skin_vertex_exact
from jaxgfx._src.skin.spline import bend_angle as bend_angle
from jaxgfx._src.skin.spline import bezier_point as bezier_point
from jaxgfx._src.skin.spline import bezier_tangent as bezier_tangent
from jaxgfx._src.skin.spline import frame_inverse as frame_inverse
from jaxgfx._src.skin.spline import spline_frame as spline_frame
from jaxgfx._src.skin.spline import spline_frames as spline_frames
from jaxgfx._src.skin.spline import spline_point as spline_point
from jaxgfx._src.skin.spline import spline_tangent as spline_tangent
from jaxgfx._src.skin.spline import start_normal as start_normal
from jaxgfx._src.skin.styles import Style as Style
from jaxgfx._src.skin.styles import apply_style as apply_style
from jaxgfx._src.skin.styles import identity_style as identity_style
from jaxgfx._src.skin.styles import make_style as make_style
from jaxgfx._src.skin.styles import muscle_style as muscle_style
from jaxgfx._src.skin.styles import radial_scale as radial_scale
from jaxgfx._src.skin.styles import rect_scale as rect_scale
from jaxgfx._src.skin.styles import sample_curve as sample_curve
from jaxgfx._src.skin.styles import sample_texture as sample_texture

__all__ = [
    "SplinePose",
    "SplineRig",
    "make_rig",
    "bind_pose",
    "validate_pose",
    "attach_children",
    "axis_angle_to_matrix",
    "forward_kinematics",
    "bezier_point",
    "bezier_tangent",
    "spline_point",
    "spline_tangent",
    "bend_angle",
    "start_normal",
    "spline_frame",
    "frame_inverse",
    "spline_frames",
    "SkinBinding",
    "bind_vertex",
    "bind_mesh",
    "brute_force_binding",
    "Style",
    "make_style",
    "identity_style",
    "muscle_style",
    "sample_texture",
    "sample_curve",
    "radial_scale",
    "rect_scale",
    "apply_style",
    "skin_vertex_exact",
    "skin_exact",
    "SampledBinding",
    "prepare_sampled",
    "sample_spline_frames",
    "skin_vertex_sampled",
    "style_offset_sampled",
    "skin_sampled",
    "skin_sampled_tables",
    "bone_transforms",
    "bone_weights_from_binding",
    "lbs_vertex",
    "linear_blend_skinning",
    "matrix_to_quaternion",
    "dual_quaternions",
    "dqs_vertex",
    "dual_quaternion_skinning",
    "FitResult",
    "style_to_params",
    "params_to_style",
    "smoothness_penalty",
    "style_loss",
    "fit_style",
    "ImageTargets",
    "render_silhouette_depth",
    "render_style_images",
    "image_loss",
    "style_image_loss",
    "fit_style_images",
    "welded_silhouette_edges",
    "GltfSkin",
    "load_gltf_skin",
    "GltfMesh",
    "load_gltf_meshes",
    "trs_matrix",
    "sample_animation",
    "joint_globals",
    "joint_matrices",
    "TAIL_JOINTS",
    "GltfSplineChain",
    "GltfChainPose",
    "gltf_spline_chain",
    "gltf_pose",
    "skin_gltf_chain",
    "limb_mesh",
    "DemoArm",
    "demo_arm",
    "demo_arm_pose",
    "demo_character",
]
