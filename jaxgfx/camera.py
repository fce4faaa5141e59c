"""One pinhole camera shared by every render pass (thesis 2.3).

All passes (terrain, static objects, characters) use the same view point, orientation,
field of view and resolution, so their depth buffers merge per pixel (2.4.2, Fig. 2.3).
Conventions: world right-handed with y up; ``yaw`` about +y (0 looks along +z), positive
``pitch`` looks up; *depth* is camera-space z; pixel ``(i, j)`` is (column, row) with row 0
at the top and centres at ``(i + 0.5, j + 0.5)``.  Angles are radians inside
:class:`Camera`; :func:`look_at`, :func:`orbit_cameras` and :func:`camera_from_degrees`
take degrees.
"""

from __future__ import annotations

from jaxgfx._src.camera import MAX_PIXELS as MAX_PIXELS
from jaxgfx._src.camera import Camera as Camera
from jaxgfx._src.camera import camera_basis as camera_basis
from jaxgfx._src.camera import camera_from_degrees as camera_from_degrees
from jaxgfx._src.camera import camera_matrix as camera_matrix
from jaxgfx._src.camera import camera_to_screen as camera_to_screen
from jaxgfx._src.camera import focal_length as focal_length
from jaxgfx._src.camera import focal_lengths as focal_lengths
from jaxgfx._src.camera import frame_points as frame_points
from jaxgfx._src.camera import look_at as look_at
from jaxgfx._src.camera import orbit_cameras as orbit_cameras
from jaxgfx._src.camera import pixel_rays as pixel_rays
from jaxgfx._src.camera import project as project
from jaxgfx._src.camera import projection_matrix as projection_matrix
from jaxgfx._src.camera import screen_to_camera as screen_to_camera
from jaxgfx._src.camera import stack_cameras as stack_cameras
from jaxgfx._src.camera import supersampled as supersampled
from jaxgfx._src.camera import validate_camera as validate_camera
from jaxgfx._src.camera import view_matrix as view_matrix
from jaxgfx._src.camera import world_to_camera as world_to_camera

__all__ = [
    "Camera",
    "camera_from_degrees",
    "look_at",
    "orbit_cameras",
    "camera_basis",
    "focal_length",
    "focal_lengths",
    "supersampled",
    "world_to_camera",
    "camera_to_screen",
    "screen_to_camera",
    "project",
    "pixel_rays",
    "camera_matrix",
    "view_matrix",
    "projection_matrix",
    "stack_cameras",
    "validate_camera",
    "frame_points",
    "MAX_PIXELS",
]
