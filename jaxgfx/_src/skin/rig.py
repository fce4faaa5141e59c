"""The spline rig: bind pose, poses and the spline hierarchy (thesis 5.4, Fig. 5.16).

A rig holds K splines of three control points each (the modified Bézier of Eq. 5.3) in their bind
pose ``B'``, one reference normal per spline (why: :mod:`jaxgfx._src.skin.spline`) and a parent
hierarchy in which a child spline's ``p1`` hangs from a control point of an earlier spline.  A
pose moves the control points and sets each spline's stiffness and twist; build it by hand or
from joint rotations with :func:`forward_kinematics`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import checking, require_finite, require_values, static_field
from jaxgfx._src.skin.geometry import _concrete

__all__ = [
    "SplinePose",
    "SplineRig",
    "make_rig",
    "bind_pose",
    "validate_pose",
    "attach_children",
    "axis_angle_to_matrix",
    "forward_kinematics",
]


# ----------------------------------------------------------------------------------------------
# pytrees
# ----------------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SplinePose:
    """Pose of K splines (thesis 5.4).

    Attributes:
        points: (K, 3, 3) control points ``p1, p2, p3`` of each spline.
        stiffness: (K,) exponent ``a >= 2`` of the modified Bézier (Eq. 5.3).
        twist: (K,) twist ``γ`` in radians, reached at ``x = 1``.
    """

    points: jax.Array
    stiffness: jax.Array
    twist: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SplineRig:
    """Splines in their bind pose, their reference normals and their hierarchy (Fig. 5.16).

    Attributes:
        bind: the bind pose ``B'`` (Eq. 5.7).
        reference_normal: (K, 3) unit normal ``b_N`` at ``x = 0`` in the bind pose, perpendicular to
            the first segment ``Δ12``.
        parent: static tuple of K ints, the parent spline of each spline or -1; parents come first.
        parent_point: static tuple of K ints in {0, 1, 2}: the parent's control point that this
            spline's ``p1`` is attached to (ignored for roots).
    """

    bind: SplinePose
    reference_normal: jax.Array
    parent: tuple[int, ...] = static_field(default=())
    parent_point: tuple[int, ...] = static_field(default=())

    @property
    def num_splines(self) -> int:
        """Number of splines K."""
        return len(self.parent)


# ----------------------------------------------------------------------------------------------
# construction and validation
# ----------------------------------------------------------------------------------------------


def _check_points(points: np.ndarray, name: str) -> None:
    if points.ndim != 3 or points.shape[1:] != (3, 3):
        raise ValueError(f"{name} must have shape (K, 3, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name} must be finite (found NaN or inf)")


def _check_stiffness(stiffness: np.ndarray, k: int, name: str) -> None:
    if stiffness.shape != (k,):
        raise ValueError(f"{name} must have shape ({k},), got {stiffness.shape}")
    if not np.all(np.isfinite(stiffness)) or np.any(stiffness < 2.0):
        raise ValueError(f"{name} must be finite and >= 2 (Eq. 5.3), got {stiffness}")


def validate_pose(rig: SplineRig, pose: SplinePose, *, where: str | None = None) -> None:
    """Raise ``ValueError`` naming the field if a concrete pose is malformed.

    Traced poses (inside ``jit``) are only shape-checked, unless inside
    :func:`~jaxgfx.checks.checked`, where their values are checked while the program runs
    (``where`` names the checking function in those messages).
    """
    k = rig.num_splines
    if tuple(jnp.shape(pose.points)) != (k, 3, 3):
        raise ValueError(f"pose.points must have shape ({k}, 3, 3), got {jnp.shape(pose.points)}")
    for name in ("stiffness", "twist"):
        if tuple(jnp.shape(getattr(pose, name))) != (k,):
            raise ValueError(f"pose.{name} must have shape ({k},)")
    pts = _concrete(pose.points)
    if pts is not None:
        _check_points(pts, "pose.points")
    a = _concrete(pose.stiffness)
    if a is not None:
        _check_stiffness(a, k, "pose.stiffness")
    tw = _concrete(pose.twist)
    if tw is not None and not np.all(np.isfinite(tw)):
        raise ValueError("pose.twist must be finite")
    if checking():
        require_finite("pose.points", pose.points, where)
        require_finite("pose.twist", pose.twist, where)
        stiff = jnp.asarray(pose.stiffness)
        rule = "{} must be finite and >= 2 (Eq. 5.3)"
        require_values("pose.stiffness", stiff >= 2.0, stiff, rule, where)


def make_rig(
    control_points,
    *,
    stiffness=None,
    twist=None,
    reference_normal=None,
    parent: Sequence[int] | None = None,
    parent_point: Sequence[int] | None = None,
) -> SplineRig:
    """Build a :class:`SplineRig` from bind-pose control points, checking every argument.

    Args:
        control_points: (K, 3, 3) bind-pose control points; both segments must have length > 0.
        stiffness: (K,) or scalar ``a >= 2`` (default 4).
        twist: (K,) bind twist in radians (default 0).
        reference_normal: (K, 3) bind normals; each is projected onto the plane normal to
            ``Δ12`` and normalized (it must not be parallel to ``Δ12``).  Default: the thesis's
            ``Δ12 × Δ23`` where the spline is bent, else any vector perpendicular to ``Δ12``.
        parent: K ints, parent spline or -1, each parent index smaller than the child's.
        parent_point: K ints in {0, 1, 2} (control point of the parent the child hangs from).

    Returns:
        The rig; arrays float32.
    """
    pts = np.asarray(control_points, dtype=np.float64)
    _check_points(pts, "control_points")
    k = pts.shape[0]
    if k < 1:
        raise ValueError("control_points must hold at least one spline")
    a = np.full(k, 4.0) if stiffness is None else np.broadcast_to(np.asarray(stiffness, float), k)
    _check_stiffness(np.asarray(a), k, "stiffness")
    tw = np.zeros(k) if twist is None else np.broadcast_to(np.asarray(twist, float), (k,))
    if not np.all(np.isfinite(tw)):
        raise ValueError("twist must be finite")
    d12 = pts[:, 1] - pts[:, 0]
    d23 = pts[:, 2] - pts[:, 1]
    l12 = np.linalg.norm(d12, axis=-1)
    l23 = np.linalg.norm(d23, axis=-1)
    if np.any(l12 < 1e-6) or np.any(l23 < 1e-6):
        raise ValueError("control_points: every spline needs p1 != p2 and p2 != p3")
    t0 = d12 / l12[:, None]
    if reference_normal is None:
        ref = np.cross(d12, d23)
        for i in range(k):
            if np.linalg.norm(ref[i]) < 1e-6 * l12[i] * l23[i]:
                helper = np.eye(3)[int(np.argmin(np.abs(t0[i])))]
                ref[i] = np.cross(t0[i], helper)
    else:
        ref = np.asarray(reference_normal, dtype=np.float64)
        if ref.shape != (k, 3) or not np.all(np.isfinite(ref)):
            raise ValueError(f"reference_normal must be a finite ({k}, 3) array, got {ref.shape}")
    ref = ref - np.sum(ref * t0, axis=-1, keepdims=True) * t0
    norms = np.linalg.norm(ref, axis=-1)
    if np.any(norms < 1e-6):
        raise ValueError("reference_normal must not be parallel to the first segment p2 - p1")
    ref = ref / norms[:, None]
    par = tuple(-1 for _ in range(k)) if parent is None else tuple(int(p) for p in parent)
    ppt = (2,) * k if parent_point is None else tuple(int(p) for p in parent_point)
    if len(par) != k or len(ppt) != k:
        raise ValueError(f"parent and parent_point must have {k} entries")
    for i, (p, j) in enumerate(zip(par, ppt, strict=True)):
        if p != -1 and not 0 <= p < i:
            raise ValueError(f"parent[{i}] = {p}: must be -1 or an earlier spline index")
        if j not in (0, 1, 2):
            raise ValueError(f"parent_point[{i}] = {j}: must be 0, 1 or 2")
    bind = SplinePose(
        points=jnp.asarray(pts, jnp.float32),
        stiffness=jnp.asarray(a, jnp.float32),
        twist=jnp.asarray(tw, jnp.float32),
    )
    return SplineRig(
        bind=bind,
        reference_normal=jnp.asarray(ref, jnp.float32),
        parent=par,
        parent_point=ppt,
    )


def bind_pose(rig: SplineRig) -> SplinePose:
    """The rig's bind pose (a convenient starting pose)."""
    return rig.bind


# ----------------------------------------------------------------------------------------------
# rig hierarchy (Fig. 5.16)
# ----------------------------------------------------------------------------------------------


def attach_children(rig: SplineRig, points: jax.Array) -> jax.Array:
    """Translate each child spline so its ``p1`` sits on its parent's attachment point.

    Args:
        rig: rig with ``parent`` / ``parent_point``.
        points: (K, 3, 3) control points whose children may be detached.

    Returns:
        (K, 3, 3) control points, parents processed before children.
    """
    out = [points[k] for k in range(rig.num_splines)]
    for k, (p, j) in enumerate(zip(rig.parent, rig.parent_point, strict=True)):
        if p >= 0:
            out[k] = out[k] + (out[p][j] - out[k][0])
    return jnp.stack(out)


def axis_angle_to_matrix(axis_angle: jax.Array) -> jax.Array:
    """Rodrigues rotation matrix (3, 3) of an axis-angle vector (3,), smooth at zero angle."""
    theta_sq = jnp.dot(axis_angle, axis_angle)
    small = theta_sq < 1e-8
    safe_sq = jnp.where(small, 1.0, theta_sq)
    theta = jnp.sqrt(safe_sq)
    # sin(θ)/θ and (1-cos θ)/θ² with their Taylor series near zero
    s = jnp.where(small, 1.0 - theta_sq / 6.0, jnp.sin(theta) / theta)
    c = jnp.where(small, 0.5 - theta_sq / 24.0, (1.0 - jnp.cos(theta)) / safe_sq)
    k = jnp.array(
        [
            [0.0, -axis_angle[2], axis_angle[1]],
            [axis_angle[2], 0.0, -axis_angle[0]],
            [-axis_angle[1], axis_angle[0], 0.0],
        ]
    )
    return jnp.eye(3) + s * k + c * (k @ k)


def forward_kinematics(
    rig: SplineRig,
    root_rotation: jax.Array,
    joint_rotation: jax.Array,
    *,
    twist: jax.Array | None = None,
    stiffness: jax.Array | None = None,
    translation: jax.Array | None = None,
) -> SplinePose:
    """Pose from joint rotations: each spline turns about ``p1`` and bends about ``p2``.

    A child inherits the rotation of the parent segment it hangs from (``parent_point`` 0 or 1:
    the first segment, 2: the second) and sits on the posed attachment point.

    Args:
        rig: the rig.
        root_rotation: (K, 3, 3) local rotation at ``p1`` (bind-world axes).
        joint_rotation: (K, 3, 3) local rotation at ``p2`` (bend of the second segment).
        twist: (K,) radians, default the bind twist.
        stiffness: (K,) default the bind stiffness.
        translation: (3,) offset of the root splines, default 0.

    Returns:
        The posed :class:`SplinePose`.
    """
    bind = rig.bind.points
    shift = jnp.zeros(3) if translation is None else translation
    seg1: list[jax.Array] = []
    seg2: list[jax.Array] = []
    pts: list[jax.Array] = []
    for k, (p, j) in enumerate(zip(rig.parent, rig.parent_point, strict=True)):
        if p >= 0:
            inherited = seg2[p] if j == 2 else seg1[p]
            p1 = pts[p][j] + inherited @ (bind[k, 0] - bind[p, j])
        else:
            inherited = jnp.eye(3)
            p1 = bind[k, 0] + shift
        g1 = inherited @ root_rotation[k]
        g2 = g1 @ joint_rotation[k]
        p2 = p1 + g1 @ (bind[k, 1] - bind[k, 0])
        p3 = p2 + g2 @ (bind[k, 2] - bind[k, 1])
        seg1.append(g1)
        seg2.append(g2)
        pts.append(jnp.stack([p1, p2, p3]))
    return SplinePose(
        points=jnp.stack(pts),
        stiffness=rig.bind.stiffness if stiffness is None else stiffness,
        twist=rig.bind.twist if twist is None else twist,
    )
