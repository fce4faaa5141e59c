"""Depth compositing of render passes, background and simple shading (thesis 2.3-2.4).

Every pass gives a :class:`Frame` (colour and camera-space depth) from the shared camera;
:func:`composite` keeps the nearest fragment per pixel, as the thesis's engine merges its
passes through the depth buffer (Fig. 2.3).
"""

from __future__ import annotations

from jaxgfx._src.compose import Frame as Frame
from jaxgfx._src.compose import background as background
from jaxgfx._src.compose import composite as composite
from jaxgfx._src.compose import composite_pair as composite_pair
from jaxgfx._src.compose import coverage as coverage
from jaxgfx._src.compose import depth_image as depth_image
from jaxgfx._src.compose import fog as fog
from jaxgfx._src.compose import lambert as lambert
from jaxgfx._src.compose import to_uint8 as to_uint8

__all__ = [
    "Frame",
    "composite",
    "composite_pair",
    "coverage",
    "background",
    "lambert",
    "fog",
    "depth_image",
    "to_uint8",
]
