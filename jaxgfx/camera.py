"""One pinhole camera shared by every render pass (thesis 2.3).

All passes (terrain, static objects, characters) use the same view point, orientation,
field of view and resolution, so their depth buffers merge per pixel (2.4.2, Fig. 2.3).
Conventions: world right-handed with y up; *depth* is camera-space z; pixel ``(i, j)`` is
(column, row) with row 0 at the top and centres at ``(i + 0.5, j + 0.5)``.  A
:class:`Camera` holds focal lengths and a principal point in pixels (an OpenCV ``K``) and
its orientation as a quaternion, so a fitted pose never locks; it converts exactly to and
from OpenCV/COLMAP ``K, [R|t]`` (:func:`camera_from_opencv`) and OpenGL/NeRF
camera-to-world matrices (:func:`camera_from_c2w`).  ``yaw`` about +y (0 looks along +z)
and positive ``pitch`` looking up remain a convenience: :func:`look_at`,
:func:`orbit_cameras` and :func:`camera_from_degrees` take degrees,
:func:`yaw_pitch_roll_rotation` radians.
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
from jaxgfx._src.camera import intrinsics_matrix as intrinsics_matrix
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
from jaxgfx._src.camera import yaw_pitch_roll as yaw_pitch_roll
from jaxgfx._src.camera_conventions import c2w_from_camera as c2w_from_camera
from jaxgfx._src.camera_conventions import camera_from_c2w as camera_from_c2w
from jaxgfx._src.camera_conventions import camera_from_opencv as camera_from_opencv
from jaxgfx._src.camera_conventions import opencv_from_camera as opencv_from_camera
from jaxgfx._src.framing import frame_points as frame_points
from jaxgfx._src.rotation import rotation_matrix as rotation_matrix
from jaxgfx._src.rotation import rotation_quaternion as rotation_quaternion
from jaxgfx._src.rotation import yaw_pitch_roll_rotation as yaw_pitch_roll_rotation

__all__ = [
    "Camera",
    "camera_from_degrees",
    "camera_from_opencv",
    "opencv_from_camera",
    "camera_from_c2w",
    "c2w_from_camera",
    "intrinsics_matrix",
    "look_at",
    "orbit_cameras",
    "yaw_pitch_roll_rotation",
    "yaw_pitch_roll",
    "rotation_matrix",
    "rotation_quaternion",
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
