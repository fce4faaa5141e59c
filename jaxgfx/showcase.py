"""The demo scene: every thesis system in one frame, everything standing on the ground.

:func:`build_demo` builds what ``jaxgfx demo`` draws: Clip-Box terrain from a height map
(ch. 3), a forest of voxel trees and Voxlap sprites ray cast from RLE columns (ch. 4) and a
skinned character whose tail is one spline with a deformation style (ch. 5).  Objects are
placed from the terrain function itself; :class:`Placement` records where, so tests can
check that nothing floats.  Real data comes from an explicit folder, ``$JAXGFX_DATA`` or
``../shared/data`` from the current directory (:func:`find_data` gives the rule); without
it the demo is procedural.
"""

from __future__ import annotations

from jaxgfx._src.showcase import CharacterPass as CharacterPass
from jaxgfx._src.showcase import Demo as Demo
from jaxgfx._src.showcase import FoxCharacter as FoxCharacter
from jaxgfx._src.showcase import GroundPatch as GroundPatch
from jaxgfx._src.showcase import Placement as Placement
from jaxgfx._src.showcase import build_demo as build_demo
from jaxgfx._src.showcase import bushy_tail_style as bushy_tail_style
from jaxgfx._src.showcase import character_pose as character_pose
from jaxgfx._src.showcase import column_top as column_top
from jaxgfx._src.showcase import data_source as data_source
from jaxgfx._src.showcase import demo_character_pass as demo_character_pass
from jaxgfx._src.showcase import demo_heightmap as demo_heightmap
from jaxgfx._src.showcase import find_data as find_data
from jaxgfx._src.showcase import forest_and_props as forest_and_props
from jaxgfx._src.showcase import fox_character as fox_character
from jaxgfx._src.showcase import fractal_heights as fractal_heights
from jaxgfx._src.showcase import ground_patch as ground_patch
from jaxgfx._src.showcase import stand_voxels as stand_voxels

__all__ = [
    "data_source",
    "find_data",
    "Placement",
    "column_top",
    "GroundPatch",
    "ground_patch",
    "fractal_heights",
    "demo_heightmap",
    "stand_voxels",
    "forest_and_props",
    "CharacterPass",
    "demo_character_pass",
    "character_pose",
    "FoxCharacter",
    "fox_character",
    "bushy_tail_style",
    "Demo",
    "build_demo",
]
