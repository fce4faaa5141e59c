"""Chapter 4: rendering static objects as run-length encoded surface voxels.

A reader's table of contents: thesis section -> function (with the implementation module
behind it).

4.3 Input data -- every input becomes a :class:`Voxels` list of coloured surface voxels
    (``voxset``): :func:`make_voxels`, :func:`dense_to_voxels`, :func:`voxels_to_dense`,
    :func:`surface_mask`, :func:`surface_voxels` (Fig. 4.10), :func:`crop_voxels`.
4.3.1 Polygon data import: :func:`voxelize_mesh` (edge interpolation, Eq. 4.1; vertex
    colours or one material colour, :data:`CLAY`; ``voxelize``).
4.3.2 Volume data import: :func:`load_volume` (MetaImage / NRRD / VTK legacy; more with
    SimpleITK, ``jaxgfx[volumes]``), :func:`volume_to_voxels` (iso threshold, default
    :func:`otsu_threshold`; cubic voxels from the spacing, :func:`resample_isotropic`,
    :func:`isotropic_shape`) (``formats``, ``volume``); Voxlap's :func:`load_vxl` /
    :func:`load_kv6`; :func:`save_scene` / :func:`load_scene` (``formats``).
4.3.3 Procedural trees:
    :func:`procedural_tree` (``tree``).
4.4.6 Pre-processing -- the RLE element ``skip << 6 | draw``: :data:`SKIP_BITS`,
    :data:`DRAW_BITS`, :data:`MAX_SKIP`, :data:`MAX_DRAW`, :func:`pack_element`,
    :func:`unpack_element` (``codec``); the pointer map and columns (Fig. 4.11):
    :class:`RLEVolume`, :func:`encode_rle`, :func:`decode_rle`, :func:`rle_stats`
    (Tables 4.1, 4.2), :func:`place_instances` (shared columns on a tile grid),
    :func:`share_columns` (copies at any position share their column tails) and
    :func:`as_jax` (``encode``).
4.4.7 Level of detail: :func:`downsample_voxels`; ``encode_rle(..., levels=L)`` (and
    ``mips="column"``, not in the thesis: levels that keep the heights, so LOD bands join
    without steps); :func:`lod_distance_for` (the band length for a cell size on screen).
4.5 Rendering: :func:`render_rle` with its static :class:`RenderSettings`, giving a
    :class:`RenderOutput`; :func:`default_num_planes`, :func:`check_camera_outside`.
4.5.1 Vanishing point:
    :func:`vanishing_point` (Eq. 4.2, 4.3).
4.5.2 Concentric planes:
    :func:`screen_segments`, :class:`Segments` (Eq. 4.4).
4.5.3 Plane parameters:
    :func:`plane_parameters`, :class:`PlaneParams`, :func:`plane_extent`.
4.5.4-4.5.5 Rasterizing and displaying the ray buffer:
    the ray buffer (Eq. 4.5 projection, first writer per texel, floating horizon and
    coverage culling) and the warp to the screen (Eq. 4.6) are stages of
    :func:`render_rle`, in one of two traversals (:class:`RenderSettings` ``traversal``):
    the scatter (every element scattered into the planes that cross its cell: a few wide
    steps a frame; :func:`scatter_limits` says which maps it takes) and the wide walk
    (each plane's 2-D DDA in blocks of cells: tens of steps a frame) (``scatter``,
    ``wide``, ``warp``).
Ray queries (not in the thesis): :func:`cast_rays` gives any batch of rays their first voxel
    (distance, voxel, face normal, colour, as a :class:`RayHits`), walking the pointer map's
    columns and skipping blocks of them that the ray passes above or below; a frame's
    per-pixel face normals, :func:`hit_normals` (``rays``).
4.5.6 Quality (smoothing, anti-aliasing, screen-space normals):
    :mod:`jaxgfx.post`.
4.6 Reference for the experiments: :func:`dda_ray_3d`, :func:`reference_render`
    (exact per-pixel 3-D DDA through the dense grid) (``reference``).

Conventions: scene coordinates are voxel units, y up; voxel ``(x, y, z)`` occupies
``[x, x+1) x [y, y+1) x [z, z+1)``.  Pre-processing is NumPy; :class:`RLEVolume` is the
JAX pytree the renderer consumes.  Renderers take the shared
:class:`jaxgfx.camera.Camera`; depth is the camera-space z, ``+inf`` where nothing was hit.

Example::

    rle = as_jax(encode_rle(procedural_tree(64, key=jax.random.key(0)), levels=2))
    out = jax.jit(render_rle)(rle, cam, settings=RenderSettings(oversample=1.0))
"""

from __future__ import annotations

from jaxgfx._src.voxel.codec import DRAW_BITS as DRAW_BITS
from jaxgfx._src.voxel.codec import MAX_DRAW as MAX_DRAW
from jaxgfx._src.voxel.codec import MAX_SKIP as MAX_SKIP
from jaxgfx._src.voxel.codec import SKIP_BITS as SKIP_BITS
from jaxgfx._src.voxel.codec import pack_element as pack_element
from jaxgfx._src.voxel.codec import unpack_element as unpack_element
from jaxgfx._src.voxel.encode import MIPS as MIPS
from jaxgfx._src.voxel.encode import RLEVolume as RLEVolume
from jaxgfx._src.voxel.encode import as_jax as as_jax
from jaxgfx._src.voxel.encode import decode_rle as decode_rle
from jaxgfx._src.voxel.encode import encode_rle as encode_rle
from jaxgfx._src.voxel.encode import place_instances as place_instances
from jaxgfx._src.voxel.encode import rle_stats as rle_stats
from jaxgfx._src.voxel.encode import share_columns as share_columns
from jaxgfx._src.voxel.formats import load_kv6 as load_kv6
from jaxgfx._src.voxel.formats import load_scene as load_scene
from jaxgfx._src.voxel.formats import load_volume as load_volume
from jaxgfx._src.voxel.formats import load_vxl as load_vxl
from jaxgfx._src.voxel.formats import save_scene as save_scene
from jaxgfx._src.voxel.formats import volume_suffix as volume_suffix
from jaxgfx._src.voxel.formats import volume_to_voxels as volume_to_voxels
from jaxgfx._src.voxel.planes import PlaneParams as PlaneParams
from jaxgfx._src.voxel.planes import Segments as Segments
from jaxgfx._src.voxel.planes import plane_extent as plane_extent
from jaxgfx._src.voxel.planes import plane_parameters as plane_parameters
from jaxgfx._src.voxel.planes import screen_segments as screen_segments
from jaxgfx._src.voxel.planes import vanishing_point as vanishing_point
from jaxgfx._src.voxel.rays import RayHits as RayHits
from jaxgfx._src.voxel.rays import cast_rays as cast_rays
from jaxgfx._src.voxel.rays import hit_normals as hit_normals
from jaxgfx._src.voxel.reference import dda_ray_3d as dda_ray_3d
from jaxgfx._src.voxel.reference import reference_render as reference_render
from jaxgfx._src.voxel.render import RenderOutput as RenderOutput
from jaxgfx._src.voxel.render import check_camera_outside as check_camera_outside
from jaxgfx._src.voxel.render import default_num_planes as default_num_planes
from jaxgfx._src.voxel.render import lod_distance_for as lod_distance_for
from jaxgfx._src.voxel.render import render_rle as render_rle
from jaxgfx._src.voxel.scatter import scatter_limits as scatter_limits
from jaxgfx._src.voxel.settings import RenderSettings as RenderSettings
from jaxgfx._src.voxel.tree import procedural_tree as procedural_tree
from jaxgfx._src.voxel.volume import isotropic_shape as isotropic_shape
from jaxgfx._src.voxel.volume import otsu_threshold as otsu_threshold
from jaxgfx._src.voxel.volume import resample_isotropic as resample_isotropic
from jaxgfx._src.voxel.voxelize import CLAY as CLAY
from jaxgfx._src.voxel.voxelize import voxelize_mesh as voxelize_mesh
from jaxgfx._src.voxel.voxset import MAX_VOXELS as MAX_VOXELS
from jaxgfx._src.voxel.voxset import Voxels as Voxels
from jaxgfx._src.voxel.voxset import crop_voxels as crop_voxels
from jaxgfx._src.voxel.voxset import dense_to_voxels as dense_to_voxels
from jaxgfx._src.voxel.voxset import downsample_voxels as downsample_voxels
from jaxgfx._src.voxel.voxset import make_voxels as make_voxels
from jaxgfx._src.voxel.voxset import surface_mask as surface_mask
from jaxgfx._src.voxel.voxset import surface_voxels as surface_voxels
from jaxgfx._src.voxel.voxset import voxels_to_dense as voxels_to_dense

__all__ = [
    # 4.3 input data: voxel sets
    "Voxels",
    "MAX_VOXELS",
    "make_voxels",
    "dense_to_voxels",
    "voxels_to_dense",
    "surface_mask",
    "surface_voxels",
    "crop_voxels",
    # 4.3.1 - 4.3.3 importers
    "voxelize_mesh",
    "CLAY",
    "load_volume",
    "volume_suffix",
    "volume_to_voxels",
    "otsu_threshold",
    "isotropic_shape",
    "resample_isotropic",
    "load_vxl",
    "load_kv6",
    "save_scene",
    "load_scene",
    "procedural_tree",
    # 4.4.6 - 4.4.7 RLE encoding
    "SKIP_BITS",
    "DRAW_BITS",
    "MAX_SKIP",
    "MAX_DRAW",
    "pack_element",
    "unpack_element",
    "RLEVolume",
    "MIPS",
    "encode_rle",
    "decode_rle",
    "rle_stats",
    "place_instances",
    "share_columns",
    "as_jax",
    "downsample_voxels",
    # 4.5 rendering
    "RenderSettings",
    "RenderOutput",
    "render_rle",
    "scatter_limits",
    "lod_distance_for",
    "default_num_planes",
    "check_camera_outside",
    "vanishing_point",
    "Segments",
    "screen_segments",
    "PlaneParams",
    "plane_parameters",
    "plane_extent",
    # ray queries
    "cast_rays",
    "RayHits",
    "hit_normals",
    # reference renderer
    "dda_ray_3d",
    "reference_render",
]
