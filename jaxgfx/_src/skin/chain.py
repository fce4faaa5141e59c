"""A glTF character with one bone chain replaced by a spline (thesis 5.9.3).

Thesis 5.9.3 argues that a spline needs fewer control joints than a bone chain: the three tail
bones of a character become one spline through their origins.  This module does that for any
:class:`~jaxgfx._src.skin.gltf.GltfSkin`:

* :func:`gltf_spline_chain` (host, once): a spline through the bind origins of three chain joints,
  the binding of every vertex the chain influences (Eq. 5.5-5.6), the chain's share of each
  vertex's weight and the other bones' weights (the chain's zeroed, *not* renormalized).
* :func:`gltf_pose` (host, per frame): the joint matrices of the clip at ``time`` (or the bind
  pose), the chain joints' posed origins and the first chain joint's rotation from its bind pose.
* :func:`skin_gltf_chain` (pure, jittable): the other bones by linear blend skinning, the chain by
  spline skinning with an optional deformation style (5.6, Eq. 5.13), summed by weight:
  ``v = Σ_{j ∉ chain} w_j M_j v_bind + w_chain · S(v)``.

The spline's start normal follows the first chain joint (its bind reference normal rotated by the
joint's rotation relative to its bind pose, projected off the first segment); its twist is 0, so
the twist of the chain's later joints is not carried over.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.checks import require_finite, static_field
from jaxgfx._src.skin.binding import SkinBinding, bind_mesh
from jaxgfx._src.skin.geometry import _normalize
from jaxgfx._src.skin.gltf import GltfSkin, joint_globals, joint_matrices, sample_animation
from jaxgfx._src.skin.rig import SplinePose, SplineRig, make_rig
from jaxgfx._src.skin.skinning import skin_vertex_exact
from jaxgfx._src.skin.styles import Style, _check_style

__all__ = [
    "TAIL_JOINTS",
    "GltfSplineChain",
    "GltfChainPose",
    "gltf_spline_chain",
    "gltf_pose",
    "skin_gltf_chain",
]

TAIL_JOINTS = ("b_Tail01", "b_Tail02", "b_Tail03")
"""The glTF sample Fox's tail chain, root first."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GltfSplineChain:
    """A skinned glTF mesh whose chain of three joints is one spline (V vertices, C on the chain).

    Attributes:
        rig: one spline through the chain joints' bind origins (``K = 1``).
        binding: (C rows) the spline binding of the vertices the chain influences, one influence.
        chain_vertex: (C,) int32 indices of those vertices in the mesh.
        chain_weight: (V,) float32 share of each vertex's weight on the chain joints.
        other_weight: (V, 4) float32 skin weights with the chain joints' zeroed (rows sum to
            ``1 - chain_weight``).
        joints: (V, 4) int32 joint indices of the skin.
        vertices: (V, 3) float32 bind positions.
        normals: (V, 3) float32 bind normals.
        bind_rotation: (3, 3) float32 global rotation of the first chain joint in the bind pose.
        chain_joints: static tuple of the three chain joint indices, root first.
    """

    rig: SplineRig
    binding: SkinBinding
    chain_vertex: jax.Array
    chain_weight: jax.Array
    other_weight: jax.Array
    joints: jax.Array
    vertices: jax.Array
    normals: jax.Array
    bind_rotation: jax.Array
    chain_joints: tuple[int, ...] = static_field(default=())


class GltfChainPose(NamedTuple):
    """Inputs of :func:`skin_gltf_chain` for one frame (J joints)."""

    matrices: jax.Array  # shape=(J, 3, 4), dtype=float32, skinning matrices G(joint) IBM
    points: jax.Array  # shape=(3, 3), dtype=float32, posed origins of the chain joints
    rotation: jax.Array  # shape=(3, 3), dtype=float32, first chain joint: posed @ bind^T


def gltf_spline_chain(
    gskin: GltfSkin, chain: Sequence[str] = TAIL_JOINTS, *, stiffness: float = 3.0
) -> GltfSplineChain:
    """Replace a chain of three joints of ``gskin`` by one spline (host; thesis 5.9.3).

    Args:
        gskin: the character (:func:`load_gltf_skin`).
        chain: three joint names, root first (default: the Fox's tail).
        stiffness: the spline's exponent ``a >= 2`` (Eq. 5.3).

    Returns:
        :class:`GltfSplineChain`, arrays on the device.

    Raises:
        ValueError: ``chain`` is not three distinct joint names of the skin, no vertex has weight
            on them, or their bind origins coincide; ``stiffness`` < 2.
    """
    names = tuple(chain) if not isinstance(chain, str) else (chain,)
    known = list(gskin.joint_names)
    if len(names) != 3 or len(set(names)) != 3:
        raise ValueError(f"chain must be three distinct joint names, got {names!r}")
    missing = [n for n in names if n not in known]
    if missing:
        raise ValueError(f"chain: joints {missing} are not in the skin (it has {known})")
    idx = [known.index(n) for n in names]
    rest_globals = joint_globals(gskin, gskin.rest_trs)
    bind_pts = rest_globals[idx, :3, 3].astype(np.float32)
    rig = make_rig(bind_pts[None], stiffness=stiffness)
    on_chain = np.isin(gskin.joints, idx)
    chain_w = np.where(on_chain, gskin.weights, 0.0).sum(1).astype(np.float32)
    vertex = np.nonzero(chain_w > 0)[0].astype(np.int32)
    if len(vertex) == 0:
        raise ValueError(f"chain: no vertex has weight on the joints {names!r}")
    binding = bind_mesh(
        rig,
        gskin.vertices[vertex],
        np.zeros((len(vertex), 1), np.int32),
        np.ones((len(vertex), 1)),
        normals=gskin.normals[vertex],
    )
    other_w = np.where(on_chain, 0.0, gskin.weights).astype(np.float32)
    return GltfSplineChain(
        rig=rig,
        binding=binding,
        chain_vertex=jnp.asarray(vertex),
        chain_weight=jnp.asarray(chain_w),
        other_weight=jnp.asarray(other_w),
        joints=jnp.asarray(gskin.joints, jnp.int32),
        vertices=jnp.asarray(gskin.vertices, jnp.float32),
        normals=jnp.asarray(gskin.normals, jnp.float32),
        bind_rotation=jnp.asarray(rest_globals[idx[0], :3, :3], jnp.float32),
        chain_joints=tuple(idx),
    )


def gltf_pose(gskin: GltfSkin, chain: GltfSplineChain, time: float | None = None) -> GltfChainPose:
    """The inputs of :func:`skin_gltf_chain` at ``time`` of the clip (host, NumPy).

    Args:
        gskin: the character the chain was built from.
        chain: :func:`gltf_spline_chain` of ``gskin``.
        time: seconds into the first animation clip, wrapped into ``[0, duration)`` like
            :func:`sample_animation`; ``None`` is the bind (rest) pose.

    Returns:
        :class:`GltfChainPose` of float32 arrays.

    Raises:
        ValueError: ``time`` is not finite; ``chain`` does not fit ``gskin``.
    """
    if len(chain.chain_joints) != 3 or max(chain.chain_joints) >= len(gskin.joint_names):
        raise ValueError("chain: was not built from this skin (joint indices out of range)")
    if chain.joints.shape != gskin.joints.shape:
        raise ValueError(
            f"chain: built for {chain.joints.shape[0]} vertices, the skin has {len(gskin.joints)}"
        )
    if time is None:
        local = gskin.rest_trs
    else:
        if not np.isfinite(float(time)):
            raise ValueError(f"time must be finite, got {time!r}")
        local = sample_animation(gskin, float(time))
    globs = joint_globals(gskin, local)
    idx = list(chain.chain_joints)
    # float64 on the host, one rounding to float32 at the end (the experiment's numbers)
    bind_rot = joint_globals(gskin, gskin.rest_trs)[idx[0], :3, :3]
    return GltfChainPose(
        matrices=jnp.asarray(joint_matrices(gskin, local)),
        points=jnp.asarray(globs[idx, :3, 3], jnp.float32),
        rotation=jnp.asarray(globs[idx[0], :3, :3] @ bind_rot.T, jnp.float32),
    )


def _chain_start_normal(rig: SplineRig, points: jax.Array, rotation: jax.Array) -> jax.Array:
    """(1, 3) posed start normal: the bind reference normal turned with the first chain joint."""
    ref = rotation @ rig.reference_normal[0]
    d = _normalize(points[1] - points[0], jnp.array([1.0, 0.0, 0.0]))
    n0 = ref - jnp.dot(ref, d) * d
    return _normalize(n0, jnp.array([0.0, 1.0, 0.0]))[None]


def skin_gltf_chain(
    chain: GltfSplineChain, pose: GltfChainPose, style: Style | None = None
) -> tuple[jax.Array, jax.Array]:
    """Skin the character: other bones by LBS, the chain as a spline with ``style`` (pure).

    ``v = Σ_{j ∉ chain} w_j M_j v_bind + w_chain · S(v)`` with ``S`` the exact spline skinning of
    Eq. 5.7 (Eq. 5.13 with the style's radial and rectangular envelopes when ``style`` is given);
    normals are blended the same way and normalized.  Jit it with ``chain`` and ``pose`` as
    arguments (every field is a traced leaf except the chain's static joint indices).

    Args:
        chain: :func:`gltf_spline_chain`.
        pose: :func:`gltf_pose`.
        style: a deformation style for the chain, or ``None`` for plain spline skinning.

    Returns:
        Positions (V, 3) and unit normals (V, 3), float32, in the glTF scene's world space.

    Raises:
        ValueError: ``pose`` arrays have the wrong shapes, or ``style`` is malformed; inside
            :func:`~jaxgfx.checks.checked` also non-finite traced pose or style values.
    """
    mats = jnp.asarray(pose.matrices, jnp.float32)
    pts = jnp.asarray(pose.points, jnp.float32)
    rot = jnp.asarray(pose.rotation, jnp.float32)
    if mats.ndim != 3 or mats.shape[1:] != (3, 4):
        raise ValueError(f"pose.matrices must have shape (J, 3, 4), got {mats.shape}")
    if pts.shape != (3, 3) or rot.shape != (3, 3):
        raise ValueError(
            f"pose.points and pose.rotation must be (3, 3), got {pts.shape}, {rot.shape}"
        )
    where = "skin_gltf_chain"
    for name, a in (("pose.matrices", mats), ("pose.points", pts), ("pose.rotation", rot)):
        require_finite(name, a, where)
    if style is not None:
        _check_style(style, where)
    styles = "none" if style is None else "both"
    rig, b = chain.rig, chain.binding
    spose = SplinePose(points=pts[None], stiffness=rig.bind.stiffness, twist=jnp.zeros(1))
    n0 = _chain_start_normal(rig, pts, rot)
    sp, sn = jax.vmap(
        lambda s, w, x, lv, ln: skin_vertex_exact(spose, n0, s, w, x, lv, ln, style, styles=styles)
    )(b.spline, b.weight, b.x, b.local, b.local_normal)
    # the other bones with their un-normalized weights: the sum of the partial blends
    m = jnp.einsum("vi,virc->vrc", chain.other_weight, mats[chain.joints])
    tw = chain.chain_weight[chain.chain_vertex][:, None]
    pos = jnp.einsum("vrc,vc->vr", m[..., :3], chain.vertices) + m[..., 3]
    pos = pos.at[chain.chain_vertex].add(tw * sp)
    nrm = jnp.einsum("vrc,vc->vr", m[..., :3], chain.normals)
    nrm = nrm.at[chain.chain_vertex].add(tw * sn)
    return pos, _normalize_rows(nrm)


def _normalize_rows(n: jax.Array) -> jax.Array:
    """Rows scaled to unit length; a zero row stays zero instead of becoming NaN."""
    length = jnp.linalg.norm(n, axis=1, keepdims=True)
    return n / jnp.where(length > 0, length, 1.0)
