"""Procedural volumetric terrain with nested Clip-Boxes (thesis chapter 3).

A terrain is a function ``f: Z^3 -> {0, 1}`` (Eq. 3.1) of one int32 world coordinate
``(x, y, z)`` (y up), written for ONE point and batched with ``jax.vmap``.  Nested
Clip-Boxes sample it around the viewer at voxel sizes ``2^l``, turn the voxels into
welded, smoothed meshes and follow the viewer with differential updates; a geometry
thread rebuilds them while the renderer draws.  World coordinates stay integers, so
the terrain is the same, exactly, at x = 0 and at x = 10^9 (3.5.3).

Thesis section -> where it lives (with the implementation module behind it):

3.4.3 Procedural volume-data creation (Eq. 3.1-3.2), ``functions.py``:
    :class:`XorTerrain`, :class:`SawTerrain`, :class:`SinTerrain` (:func:`int_sin`),
    :class:`FunctionTerrain`, :class:`Union`, :class:`Intersection`, :class:`Difference`.
3.4.3 CSG terrain with spatial bins (Fig. 3.5; 50 000 operations in 3.5.2), ``csg.py``:
    :class:`CSGTerrain`, :func:`csg_terrain`, :func:`random_csg_terrain`,
    ``PRIMITIVE_SPHERE`` / ``PRIMITIVE_BOX`` / ``PRIMITIVE_CYLINDER``.
3.5.2 Elevation files (GeoTIFF, SRTM .hgt, ESRI .asc, USGS .dem, images, arrays), ``elevation.py``:
    :func:`read_heightmap` (:class:`HeightmapData`: heights, metres per sample along x
    and z, height unit, CRS, NODATA voids filled; :class:`NodataWarning`),
    :func:`load_heightmap`, :func:`metres_per_degree`.
3.5.2 height maps (Fig. 3.16) and 3.3.1 existing volumes, ``heightmap.py``:
    :func:`heightmap_terrain` (:class:`HeightmapTerrain` with its
    :class:`HeightmapMapping`; ``IMAGE_RELIEF``, ``APRON_FADE``), :func:`ground_height`,
    :func:`default_viewer`, :func:`volume_terrain` (:class:`VolumeTerrain`).  A sample
    (r, c) with value v stands at x = origin_x + (c + 0.5) cell_x, z = origin_z +
    (r + 0.5) cell_z, y = base + (v - min_value) vertical_scale; heights are bilinear
    between samples, fade into a flat apron beyond the map, and voxel (x, y, z) is solid
    iff y + 0.5 < ground_height(x + 0.5, z + 0.5).
3.4.3 Validating and sampling any terrain, ``sampling.py``:
    :func:`as_terrain`, :func:`check_terrain`, :func:`check_viewer`, :func:`sample_terrain`.
3.4.1-3.4.2 Clip-Box and 3.4.3 filling it, ``clipbox.py``:
    :class:`ClipBox`, :func:`clipbox_origin`, :func:`sample_clipbox`.
3.4.5 Nesting (Fig. 3.2, 3.10), ``clipbox.py``:
    :class:`NestedClipBoxes`, :func:`nested_origins`, :func:`is_nested`, :func:`max_levels`.
3.4.6 Moving the view-point (Fig. 3.11), ``clipbox.py``:
    :func:`slab_thickness`, :func:`shift_clipbox`, :func:`reused_fraction`.
3.4.4 Volume-data to polygon conversion (Fig. 3.4, 3.8), ``meshing.py``:
    :func:`voxels_to_mesh` (:class:`ClipBoxMesh`).
3.4.5 Seams between levels (Fig. 3.6-3.7), ``meshing.py``:
    :func:`seam_occupancy`, :func:`weld_seam`, :func:`visible_faces`.
3.4.7 Geometry post-processing (Fig. 3.9, 3.12-3.14, Table 3.1), ``postprocess.py``:
    :func:`pattern_filter`, :func:`smooth_mesh`, :func:`mesh_normals`, :func:`blend_seam`,
    :func:`subdivide_mesh` (:class:`SubdividedMesh`).
3.4.5 / 3.5.3 Drawing the levels (Fig. 3.1 thread 2), ``display.py``:
    :func:`level_views`, :func:`level_arrays`, :func:`render_levels`,
    :func:`weld_mesh` (the levels as one surface), :func:`mesh_to_trimesh`.
3.5.2 Shading by slope and height, fog, sky (the HVOX terrain shader), ``shading.py``:
    :func:`terrain_colors`, :func:`render_terrain`, ``SKY_HORIZON``, ``SKY_ZENITH``.
3.3.1 / 3.4.6 The update driver (Fig. 3.1 thread 1), ``pipeline.py``:
    :class:`ClipBoxPipeline`.
3.5.4 Concurrent generation and visualization (Fig. 3.1), ``worker.py``:
    :class:`GeometryWorker`.
"""

from __future__ import annotations

from jaxgfx._src.terrain.clipbox import ClipBox as ClipBox
from jaxgfx._src.terrain.clipbox import NestedClipBoxes as NestedClipBoxes
from jaxgfx._src.terrain.clipbox import clipbox_origin as clipbox_origin
from jaxgfx._src.terrain.clipbox import is_nested as is_nested
from jaxgfx._src.terrain.clipbox import max_levels as max_levels
from jaxgfx._src.terrain.clipbox import nested_origins as nested_origins
from jaxgfx._src.terrain.clipbox import reused_fraction as reused_fraction
from jaxgfx._src.terrain.clipbox import sample_clipbox as sample_clipbox
from jaxgfx._src.terrain.clipbox import shift_clipbox as shift_clipbox
from jaxgfx._src.terrain.clipbox import slab_thickness as slab_thickness
from jaxgfx._src.terrain.csg import PRIMITIVE_BOX as PRIMITIVE_BOX
from jaxgfx._src.terrain.csg import PRIMITIVE_CYLINDER as PRIMITIVE_CYLINDER
from jaxgfx._src.terrain.csg import PRIMITIVE_SPHERE as PRIMITIVE_SPHERE
from jaxgfx._src.terrain.csg import CSGTerrain as CSGTerrain
from jaxgfx._src.terrain.csg import csg_terrain as csg_terrain
from jaxgfx._src.terrain.csg import random_csg_terrain as random_csg_terrain
from jaxgfx._src.terrain.display import level_arrays as level_arrays
from jaxgfx._src.terrain.display import level_views as level_views
from jaxgfx._src.terrain.display import mesh_to_trimesh as mesh_to_trimesh
from jaxgfx._src.terrain.display import render_levels as render_levels
from jaxgfx._src.terrain.display import weld_mesh as weld_mesh
from jaxgfx._src.terrain.elevation import HeightmapData as HeightmapData
from jaxgfx._src.terrain.elevation import NodataWarning as NodataWarning
from jaxgfx._src.terrain.elevation import load_heightmap as load_heightmap
from jaxgfx._src.terrain.elevation import metres_per_degree as metres_per_degree
from jaxgfx._src.terrain.elevation import read_heightmap as read_heightmap
from jaxgfx._src.terrain.functions import Difference as Difference
from jaxgfx._src.terrain.functions import FunctionTerrain as FunctionTerrain
from jaxgfx._src.terrain.functions import Intersection as Intersection
from jaxgfx._src.terrain.functions import SawTerrain as SawTerrain
from jaxgfx._src.terrain.functions import SinTerrain as SinTerrain
from jaxgfx._src.terrain.functions import Union as Union
from jaxgfx._src.terrain.functions import XorTerrain as XorTerrain
from jaxgfx._src.terrain.functions import int_sin as int_sin
from jaxgfx._src.terrain.heightmap import APRON_FADE as APRON_FADE
from jaxgfx._src.terrain.heightmap import IMAGE_RELIEF as IMAGE_RELIEF
from jaxgfx._src.terrain.heightmap import HeightmapMapping as HeightmapMapping
from jaxgfx._src.terrain.heightmap import HeightmapTerrain as HeightmapTerrain
from jaxgfx._src.terrain.heightmap import VolumeTerrain as VolumeTerrain
from jaxgfx._src.terrain.heightmap import default_viewer as default_viewer
from jaxgfx._src.terrain.heightmap import ground_height as ground_height
from jaxgfx._src.terrain.heightmap import heightmap_terrain as heightmap_terrain
from jaxgfx._src.terrain.heightmap import volume_terrain as volume_terrain
from jaxgfx._src.terrain.meshing import ClipBoxMesh as ClipBoxMesh
from jaxgfx._src.terrain.meshing import seam_occupancy as seam_occupancy
from jaxgfx._src.terrain.meshing import visible_faces as visible_faces
from jaxgfx._src.terrain.meshing import voxels_to_mesh as voxels_to_mesh
from jaxgfx._src.terrain.meshing import weld_seam as weld_seam
from jaxgfx._src.terrain.pipeline import ClipBoxPipeline as ClipBoxPipeline
from jaxgfx._src.terrain.postprocess import SubdividedMesh as SubdividedMesh
from jaxgfx._src.terrain.postprocess import blend_seam as blend_seam
from jaxgfx._src.terrain.postprocess import mesh_normals as mesh_normals
from jaxgfx._src.terrain.postprocess import pattern_filter as pattern_filter
from jaxgfx._src.terrain.postprocess import smooth_mesh as smooth_mesh
from jaxgfx._src.terrain.postprocess import subdivide_mesh as subdivide_mesh
from jaxgfx._src.terrain.sampling import as_terrain as as_terrain
from jaxgfx._src.terrain.sampling import check_terrain as check_terrain
from jaxgfx._src.terrain.sampling import check_viewer as check_viewer
from jaxgfx._src.terrain.sampling import sample_terrain as sample_terrain
from jaxgfx._src.terrain.shading import SKY_HORIZON as SKY_HORIZON
from jaxgfx._src.terrain.shading import SKY_ZENITH as SKY_ZENITH
from jaxgfx._src.terrain.shading import render_terrain as render_terrain
from jaxgfx._src.terrain.shading import terrain_colors as terrain_colors
from jaxgfx._src.terrain.worker import GeometryWorker as GeometryWorker

__all__ = [
    # 3.4.3 terrain functions (Eq. 3.1-3.2)
    "XorTerrain",
    "SawTerrain",
    "SinTerrain",
    "int_sin",
    "FunctionTerrain",
    "Union",
    "Intersection",
    "Difference",
    # 3.4.3 CSG terrain (Fig. 3.5)
    "CSGTerrain",
    "PRIMITIVE_SPHERE",
    "PRIMITIVE_BOX",
    "PRIMITIVE_CYLINDER",
    "csg_terrain",
    "random_csg_terrain",
    # 3.5.2 height maps, 3.3.1 volumes
    "HeightmapData",
    "NodataWarning",
    "HeightmapMapping",
    "HeightmapTerrain",
    "VolumeTerrain",
    "read_heightmap",
    "load_heightmap",
    "metres_per_degree",
    "heightmap_terrain",
    "IMAGE_RELIEF",
    "APRON_FADE",
    "ground_height",
    "default_viewer",
    "volume_terrain",
    # 3.4.3 validation and sampling
    "as_terrain",
    "check_terrain",
    "check_viewer",
    "sample_terrain",
    # 3.4.1-3.4.3 Clip-Box
    "ClipBox",
    "clipbox_origin",
    "sample_clipbox",
    # 3.4.5 nesting
    "NestedClipBoxes",
    "nested_origins",
    "is_nested",
    "max_levels",
    # 3.4.6 moving the view-point
    "slab_thickness",
    "shift_clipbox",
    "reused_fraction",
    # 3.4.4-3.4.5 polygons and seams
    "ClipBoxMesh",
    "voxels_to_mesh",
    "seam_occupancy",
    "weld_seam",
    "visible_faces",
    # 3.4.7 post-processing
    "pattern_filter",
    "smooth_mesh",
    "mesh_normals",
    "blend_seam",
    "SubdividedMesh",
    "subdivide_mesh",
    # drawing the levels
    "level_views",
    "level_arrays",
    "render_levels",
    "mesh_to_trimesh",
    "weld_mesh",
    # shading by slope and height, fog, sky
    "SKY_HORIZON",
    "SKY_ZENITH",
    "terrain_colors",
    "render_terrain",
    # 3.3.1, 3.5.4 driver and geometry thread
    "ClipBoxPipeline",
    "GeometryWorker",
]
