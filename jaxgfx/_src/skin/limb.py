"""The chapter's example limb: one arm on one spline with a muscle style (thesis ch. 5).

:func:`demo_arm` builds the arm once for every caller (the scene's character pass, ``jaxgfx skin``
and :func:`demo_character`); :func:`demo_arm_pose` bends and twists it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.skin.binding import SkinBinding, bind_mesh
from jaxgfx._src.skin.rig import (
    SplinePose,
    SplineRig,
    axis_angle_to_matrix,
    forward_kinematics,
    make_rig,
)
from jaxgfx._src.skin.skinning import skin_exact
from jaxgfx._src.skin.styles import _style_flags, muscle_style

__all__ = ["limb_mesh", "DemoArm", "demo_arm", "demo_arm_pose", "demo_character"]


def limb_mesh(n_around: int, n_along: int, radius: float, length: float):
    """Closed, slightly tapered tube along +y from the origin (a demo limb).

    Returns:
        vertices (V, 3), outward normals (V, 3) float32 and faces (F, 3) int32 (outward).
    """
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    y = np.linspace(0.0, length, n_along)
    yy, aa = np.meshgrid(y, a, indexing="ij")
    # slightly tapered like a limb
    r = radius * (1.0 - 0.25 * yy / length)
    v = np.stack([r * np.cos(aa), yy, r * np.sin(aa)], -1).reshape(-1, 3)
    n = np.stack([np.cos(aa), 0 * yy, np.sin(aa)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_along - 1), np.arange(n_around), indexing="ij")
    a0 = (i * n_around + j).ravel()
    a1 = (i * n_around + (j + 1) % n_around).ravel()
    b0, b1 = a0 + n_around, a1 + n_around
    faces = np.concatenate([np.stack([a0, b1, a1], 1), np.stack([a0, b0, b1], 1)])
    base = len(v)
    v = np.concatenate([v, [[0.0, 0.0, 0.0], [0.0, length, 0.0]]])
    n = np.concatenate([n, [[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]]])
    ring0 = np.arange(n_around)
    ring1 = (n_along - 1) * n_around + ring0
    cap0 = np.stack([np.full(n_around, base), ring0, np.roll(ring0, -1)], 1)
    cap1 = np.stack([np.full(n_around, base + 1), np.roll(ring1, -1), ring1], 1)
    faces = np.concatenate([faces, cap0, cap1])
    return v.astype(np.float32), n.astype(np.float32), faces.astype(np.int32)


class DemoArm(NamedTuple):
    """The demo arm bound to its rig (:func:`demo_arm`); V vertices, F faces."""

    vertices: np.ndarray  # shape=(V, 3), float32, bind pose, standing on the origin along +y
    normals: np.ndarray  # shape=(V, 3), float32, outward unit normals
    faces: np.ndarray  # shape=(F, 3), int32, outward
    rig: SplineRig  # one spline p1 = 0, p2 = (0, 1, 0), p3 = (0, 2, 0), stiffness 4, normal +x
    binding: SkinBinding  # every vertex on the one spline with weight 1


def demo_arm() -> DemoArm:
    """The demo arm: a tapered limb (length 2, radius 0.22) bound to one straight spline.

    The one builder behind the scene's character pass, ``jaxgfx skin`` and
    :func:`demo_character`; pose it with :func:`demo_arm_pose`.
    """
    v, n, faces = limb_mesh(24, 41, 0.22, 2.0)
    rig = make_rig(
        np.array([[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.0]]], np.float32),
        stiffness=4.0,
        reference_normal=[[1.0, 0.0, 0.0]],
    )
    binding = bind_mesh(rig, v, np.zeros((len(v), 1), np.int32), np.ones((len(v), 1)), normals=n)
    return DemoArm(vertices=v, normals=n, faces=faces, rig=rig, binding=binding)


def demo_arm_pose(rig: SplineRig, bend: float | jax.Array, twist: float | jax.Array) -> SplinePose:
    """Pose of the demo arm: bend ``bend`` radians about ``-x`` at the elbow, twist ``twist``.

    Args:
        rig: the arm's rig (``demo_arm().rig``).
        bend: () elbow bend in radians (a Python float or a traced scalar).
        twist: () twist ``γ`` in radians.

    Returns:
        The pose (:func:`forward_kinematics` with the root unrotated).

    Raises:
        ValueError: a concrete ``bend`` or ``twist`` beyond one turn (2 pi), which is
            almost certainly an angle in degrees.
    """
    for name, value in (("bend", bend), ("twist", twist)):
        if not isinstance(value, jax.core.Tracer) and np.any(np.abs(np.asarray(value)) > 2 * np.pi):
            raise ValueError(
                f"{name} is in radians: {float(np.max(np.abs(value))):g} is more than one turn "
                f"(degrees? use math.radians)"
            )
    rot = axis_angle_to_matrix(jnp.stack([-bend, 0.0, 0.0]).astype(jnp.float32))
    twists = jnp.reshape(jnp.asarray(twist, jnp.float32), (1,))
    return forward_kinematics(rig, jnp.eye(3)[None], rot[None], twist=twists)


_skin_exact_jit = jax.jit(skin_exact, static_argnames=("styles", "dominant_only"))


def demo_character(phase: float = 0.25, *, styles: str = "both"):
    """A styled arm for demo scenes: one spline, bending and twisting with ``phase`` in [0, 1).

    The arm stands on the origin along +y (length 2, radius 0.22), bends about the x axis at its
    middle (up to about 115°) and carries :func:`muscle_style`.

    Returns:
        vertices (V, 3), faces (F, 3) int32 and unit normals (V, 3), NumPy arrays.
    """
    _style_flags(styles)
    arm = demo_arm()
    bend = 1.0 * (1.0 - math.cos(2 * math.pi * phase))
    pose = demo_arm_pose(arm.rig, bend, 0.6 * math.sin(2 * math.pi * phase))
    style = muscle_style() if styles != "none" else None
    # a demo entry point returning NumPy, so it compiles its own call (like bind_mesh)
    pos, nrm = _skin_exact_jit(arm.rig, pose, arm.binding, style, styles=styles)
    return np.asarray(pos), arm.faces, np.asarray(nrm)
