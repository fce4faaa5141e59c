"""Tests for jaxgfx.skin: splines, frames, binding, skinning, styles and LBS/DQS baselines."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgfx import skin

# float32 tolerances, named once
_TIGHT = 2e-5  # identities that hold up to rounding
_FD_TOL = 2e-3  # finite differences in float32
_GRAD_TOL = 5e-2  # check_grads in float32 (relative)
_SAMPLED_TOL = 5e-3  # exact vs sampled skinning, in units of the limb length (S = 32)


def _cylinder(n_around: int = 12, n_along: int = 11, radius: float = 0.2, length: float = 2.0):
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    z = np.linspace(0.0, length, n_along)
    zz, aa = np.meshgrid(z, a, indexing="ij")
    v = np.stack([radius * np.cos(aa), radius * np.sin(aa), zz], -1).reshape(-1, 3)
    n = np.stack([np.cos(aa), np.sin(aa), 0 * zz], -1).reshape(-1, 3)
    return v.astype(np.float32), n.astype(np.float32)


STRAIGHT = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]], np.float32)


@pytest.fixture(scope="module")
def limb():
    """One straight spline along z with a cylinder bound to it (reference normal +x)."""
    rig = skin.make_rig(STRAIGHT, stiffness=4.0, reference_normal=[[1.0, 0.0, 0.0]])
    v, n = _cylinder()
    binding = skin.bind_mesh(
        rig, v, np.zeros((len(v), 1), np.int32), np.ones((len(v), 1)), normals=n
    )
    return rig, binding


def _bent_pose(rig, bend: float, twist: float = 0.0):
    rot = skin.axis_angle_to_matrix(jnp.array([bend, 0.0, 0.0]))
    return skin.forward_kinematics(
        rig, jnp.eye(3)[None], rot[None], twist=jnp.array([twist], jnp.float32)
    )


lbs_jit = jax.jit(skin.linear_blend_skinning)
dqs_jit = jax.jit(skin.dual_quaternion_skinning)
bones_jit = jax.jit(skin.bone_transforms)
skin_exact_jit = jax.jit(skin.skin_exact, static_argnames=("styles", "dominant_only"))
_skin_sampled_jit = jax.jit(skin.skin_sampled, static_argnames=("samples", "styles", "subrows"))


def skin_sampled_jit(rig, pose, binding, style=None, *, samples=32, styles="none"):
    prepared = skin.prepare_sampled(binding, samples)
    return _skin_sampled_jit(rig, pose, prepared, style, samples=samples, styles=styles)


# ---------------------------------------------------------------- splines and frames


def test_modified_bezier_ends_and_a2_equals_bezier():
    rng = np.random.default_rng(0)
    pts = jnp.asarray(rng.normal(size=(3, 3)), jnp.float32)
    np.testing.assert_allclose(skin.spline_point(pts, 5.0, 0.0), pts[0], atol=_TIGHT)
    np.testing.assert_allclose(skin.spline_point(pts, 5.0, 1.0), pts[2], atol=_TIGHT)
    for x in np.linspace(0, 1, 7):
        np.testing.assert_allclose(
            skin.spline_point(pts, 2.0, x), skin.bezier_point(pts, x), atol=_TIGHT
        )
        np.testing.assert_allclose(
            skin.spline_tangent(pts, 2.0, x), skin.bezier_tangent(pts, x), atol=1e-4
        )


@pytest.mark.parametrize("a", [2.0, 3.5, 8.0])
def test_spline_derivative_matches_finite_differences(a):
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(3, 3))
    h = 1e-4
    for x in [0.1, 0.37, 0.5, 0.9]:
        fd = (
            np.asarray(skin.spline_point(jnp.asarray(pts), a, x + h), np.float64)
            - np.asarray(skin.spline_point(jnp.asarray(pts), a, x - h), np.float64)
        ) / (2 * h)
        # slow NumPy reference of Eq. 5.3 in float64
        ref = a * (1 - x) ** (a - 1) * (pts[1] - pts[0]) + a * x ** (a - 1) * (pts[2] - pts[1])
        np.testing.assert_allclose(skin.spline_tangent(jnp.asarray(pts), a, x), ref, rtol=1e-5)
        np.testing.assert_allclose(fd, ref, atol=_FD_TOL * max(1.0, np.abs(ref).max()) * 10)
        jac = jax.jacfwd(skin.spline_point, argnums=2)(jnp.asarray(pts, jnp.float32), a, x)
        np.testing.assert_allclose(jac, ref, rtol=1e-4, atol=1e-5)


def _frame(points, a, twist, ref, x):
    n0 = skin.start_normal(points, ref, points)
    return skin.spline_frame(points, a, twist, n0, x)


@pytest.mark.parametrize("bent", [False, True])
def test_frame_orthonormal_origin_tangent(bent):
    pts = jnp.asarray(STRAIGHT[0])
    if bent:
        pts = pts.at[2].set(jnp.array([0.0, -0.8, 1.3]))
    ref = jnp.array([1.0, 0.0, 0.0])
    for x in [0.0, 0.25, 0.5, 0.8, 1.0]:
        frame = _frame(pts, 3.0, 0.7, ref, x)
        rot = frame[:, :3]
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-5)
        np.testing.assert_allclose(frame[:, 3], skin.spline_point(pts, 3.0, x), atol=_TIGHT)
        tangent = skin.spline_tangent(pts, 3.0, x)
        np.testing.assert_allclose(frame[:, 2], tangent / jnp.linalg.norm(tangent), atol=1e-5)
        # b_B = b_N x b_T as in Eq. 5.4
        np.testing.assert_allclose(frame[:, 1], jnp.cross(frame[:, 0], frame[:, 2]), atol=1e-5)


def test_frame_equals_thesis_normal_for_hinge_bend():
    """With the hinge axis as reference normal, b_N is the thesis's normalized Δ12 × Δ23."""
    pts = jnp.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -0.7, 1.5]])
    d12, d23 = pts[1] - pts[0], pts[2] - pts[1]
    thesis_n = jnp.cross(d12, d23) / jnp.linalg.norm(jnp.cross(d12, d23))
    for x in [0.0, 0.3, 0.6, 1.0]:
        frame = _frame(pts, 4.0, 0.0, thesis_n, x)
        np.testing.assert_allclose(frame[:, 0], thesis_n, atol=1e-5)


def test_straight_spline_frame_finite_with_gradients():
    pts = jnp.asarray(STRAIGHT[0])
    ref = jnp.array([1.0, 0.0, 0.0])

    @jax.jit
    def f(points, twist, a):
        return jnp.sum(jnp.sin(_frame(points, a, twist, ref, 0.4)))

    grads = jax.grad(f, argnums=(0, 1, 2))(pts, 0.3, 4.0)
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads)
    check_grads(
        f, (pts, 0.3, 4.0), order=1, modes=["rev"], eps=1e-3, atol=_GRAD_TOL, rtol=_GRAD_TOL
    )
    # twist of a straight spline rotates b_N about the axis by twist * x
    frame = _frame(pts, 4.0, math.pi / 2, ref, 1.0)
    np.testing.assert_allclose(frame[:, 0], [0.0, 1.0, 0.0], atol=1e-5)
    # the bend angle has a finite gradient at 0
    g = jax.grad(lambda p: skin.bend_angle(p))(pts)
    assert bool(jnp.all(jnp.isfinite(g)))


# ---------------------------------------------------------------- binding


def test_binding_matches_brute_force():
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 1.2]], np.float32)
    rig = skin.make_rig(pts[None], stiffness=3.0, reference_normal=[[1.0, 0.0, 0.0]])
    rng = np.random.default_rng(2)
    xs = rng.uniform(0.02, 0.98, 60)
    n0 = rig.reference_normal[0]
    frames = jax.vmap(lambda x: skin.spline_frame(jnp.asarray(pts), 3.0, 0.0, n0, x))(xs)
    offs = rng.normal(size=(60, 2)) * 0.08  # close to the curve: the foot point is unique
    verts = np.asarray(
        frames[:, :, 3] + frames[:, :, 0] * offs[:, :1] + frames[:, :, 1] * offs[:, 1:]
    )
    binding = skin.bind_mesh(rig, verts, np.zeros((60, 1), np.int32), np.ones((60, 1)))
    ref = skin.brute_force_binding(pts, 3.0, verts)
    np.testing.assert_allclose(np.asarray(binding.x[:, 0]), ref, atol=1e-3)
    # v' = B'^{-1} v reconstructs v (Eq. 5.6) and lies in the plane v'_z = 0 (Eq. 5.5)
    back = jnp.einsum("vij,vj->vi", frames[:, :, :3], binding.local[:, 0]) + frames[:, :, 3]
    np.testing.assert_allclose(back, verts, atol=2e-3)
    np.testing.assert_allclose(binding.local[:, 0, 2], 0.0, atol=1e-3)


# ---------------------------------------------------------------- skinning


def test_bind_pose_is_identity(limb):
    rig, binding = limb
    for fn in (skin_exact_jit, skin_sampled_jit):
        pos, nrm = fn(rig, rig.bind, binding)
        np.testing.assert_allclose(pos, binding.rest, atol=1e-5)
        np.testing.assert_allclose(nrm, binding.rest_normal, atol=1e-5)


def test_exact_vs_sampled_within_tolerance(limb):
    rig, binding = limb
    pose = _bent_pose(rig, 1.3, twist=2.0)
    pe, ne = skin_exact_jit(rig, pose, binding)
    ps, ns = skin_sampled_jit(rig, pose, binding)
    assert bool(jnp.all(jnp.isfinite(pe))) and bool(jnp.all(jnp.isfinite(ps)))
    assert float(jnp.max(jnp.abs(pe - ps))) < _SAMPLED_TOL * 2.0
    assert float(jnp.max(jnp.abs(ne - ps * 0 - ns))) < 5e-2
    # the spline skin keeps the cross-section radius (no collapse) at the bent joint
    n0 = jax.vmap(skin.start_normal)(rig.bind.points, rig.reference_normal, pose.points)
    centres = jax.vmap(lambda x: skin.spline_point(pose.points[0], pose.stiffness[0], x))(
        binding.x[:, 0]
    )
    del n0
    np.testing.assert_allclose(jnp.linalg.norm(pe - centres, axis=1), 0.2, atol=1e-4)


def test_exact_skinning_matches_numpy_reference(limb):
    """Eq. 5.7 with frames evaluated independently in NumPy (float64)."""
    rig, binding = limb
    pose = _bent_pose(rig, 0.9, twist=-0.6)
    pts = np.asarray(pose.points[0], np.float64)
    a = float(pose.stiffness[0])
    twist = float(pose.twist[0])
    out = np.asarray(skin_exact_jit(rig, pose, binding)[0])
    for i in range(0, len(out), 17):
        x = float(binding.x[i, 0])
        d12, d23 = pts[1] - pts[0], pts[2] - pts[1]
        origin = pts[0] + (1 - (1 - x) ** a) * d12 + x**a * d23
        t = a * (1 - x) ** (a - 1) * d12 + a * x ** (a - 1) * d23
        t /= np.linalg.norm(t)
        # the hinge bend about +x keeps the rotation-minimizing normal at +x
        n = np.array([1.0, 0.0, 0.0])
        n = np.cos(twist * x) * n + np.sin(twist * x) * np.cross(t, n)
        b = np.cross(n, t)
        lv = np.asarray(binding.local[i, 0], np.float64)
        ref = origin + lv[0] * n + lv[1] * b + lv[2] * t
        np.testing.assert_allclose(out[i], ref, atol=1e-4)


def test_jit_and_vmap_paths_agree(limb):
    rig, binding = limb
    poses = [_bent_pose(rig, b, t) for b, t in [(0.2, 0.0), (1.0, 1.0), (2.0, -2.5)]]
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *poses)
    batched = jax.jit(jax.vmap(lambda p: skin.skin_exact(rig, p, binding)[0]))(stacked)
    eager = skin.skin_exact(rig, poses[1], binding)[0]
    np.testing.assert_allclose(batched[1], eager, atol=1e-5)
    for i, pose in enumerate(poses):
        np.testing.assert_allclose(skin_exact_jit(rig, pose, binding)[0], batched[i], atol=1e-5)


def test_skinning_gradients_straight_and_on_axis():
    """Finite gradients for a straight spline and a vertex on the spline axis (α undefined)."""
    rig = skin.make_rig(STRAIGHT, stiffness=4.0, reference_normal=[[1.0, 0.0, 0.0]])
    verts = np.array([[0.0, 0.0, 0.7], [0.0, 0.0, 1.4], [0.15, -0.1, 1.0]], np.float32)
    binding = skin.bind_mesh(rig, verts, np.zeros((3, 1), np.int32), np.ones((3, 1)))
    np.testing.assert_allclose(binding.local[:2, 0], 0.0, atol=1e-6)  # really on the axis
    rng = np.random.default_rng(3)
    style = skin.make_style(1.0 + 0.3 * rng.random((3, 5, 6)), 1.0 + 0.3 * rng.random((3, 6)))

    @jax.jit
    def loss(points, twist, textures, curves):
        pose = skin.SplinePose(points=points, stiffness=rig.bind.stiffness, twist=twist)
        st = skin.Style(textures=textures, curves=curves, hollow=style.hollow)
        exact = skin.skin_exact(rig, pose, binding, st, styles="both")
        return jnp.sum(jnp.sin(3.0 * exact[0])) + jnp.sum(exact[1])

    args = (rig.bind.points, jnp.array([0.0]), style.textures, style.curves)
    grads = jax.grad(loss, argnums=(0, 1, 2, 3))(*args)
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads)

    # check_grads on the style of an on-axis vertex, w.r.t. the curves, textures and the vertex
    @jax.jit
    def styled(local, textures, curves):
        st = skin.Style(textures=textures, curves=curves, hollow=jnp.float32(0.0))
        return skin.apply_style(st, local, local, 0.3, 0.4, 0.2)[0]

    on_axis = jnp.zeros(3)
    g = jax.jacrev(styled, argnums=(0, 1, 2))(on_axis, style.textures, style.curves)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in g)
    check_grads(
        styled,
        (jnp.array([0.05, -0.1, 0.0]), style.textures, style.curves),
        order=1,
        modes=["rev"],
        eps=1e-3,
        atol=_GRAD_TOL,
        rtol=_GRAD_TOL,
    )


# ---------------------------------------------------------------- styles


def test_identity_style_is_no_change(limb):
    rig, binding = limb
    style = skin.identity_style((8, 9), 7)
    for bend, twist in [(0.0, 0.0), (1.2, 0.5), (2.8, -3.0)]:
        pose = _bent_pose(rig, bend, twist)
        plain = skin_exact_jit(rig, pose, binding)[0]
        for styles in ("radial", "rect"):
            styled = skin_exact_jit(rig, pose, binding, style, styles=styles)[0]
            np.testing.assert_allclose(styled, plain, atol=_TIGHT)
    # Eq. 5.10 directly on the scale function, all poses
    rng = np.random.default_rng(4)
    for _ in range(20):
        alpha = rng.uniform(0, math.pi)
        s = skin.radial_scale(
            style,
            rng.random(),
            math.cos(alpha),
            abs(math.sin(alpha)),
            alpha / math.pi,
            rng.random(),
            3 * rng.random(),
        )
        np.testing.assert_allclose(s, 1.0, atol=1e-6)


def test_radial_scale_matches_numpy_reference():
    rng = np.random.default_rng(5)
    tex = rng.random((3, 4, 5)).astype(np.float32) + 0.5
    style = skin.make_style(tex, np.ones((3, 5)))
    for _ in range(10):
        x, alpha, beta, gamma = rng.random(), rng.uniform(0, math.pi), rng.random(), rng.random()
        # bilinear lookup reference
        fr, fc = alpha / math.pi * 3, x * 4
        r0, c0 = min(int(fr), 2), min(int(fc), 3)
        tr, tc = fr - r0, fc - c0
        t = (
            tex[:, r0, c0] * (1 - tr) * (1 - tc)
            + tex[:, r0, c0 + 1] * (1 - tr) * tc
            + tex[:, r0 + 1, c0] * tr * (1 - tc)
            + tex[:, r0 + 1, c0 + 1] * tr * tc
        )
        w = np.array([max(-math.cos(alpha), 0) * beta, abs(math.sin(alpha)) * beta, gamma])
        ref = (w @ t) / max(1.0, w.sum()) + max(1.0 - w.sum(), 0.0)
        got = skin.radial_scale(
            style, x, math.cos(alpha), abs(math.sin(alpha)), alpha / math.pi, beta, gamma
        )
        np.testing.assert_allclose(got, ref, rtol=1e-5)


def test_style_changes_only_cross_section_and_hollow(limb):
    rig, binding = limb
    pose = _bent_pose(rig, 1.5)
    tex = np.full((3, 4, 4), 1.5)
    plain = skin_exact_jit(rig, pose, binding)[0]
    bulge = skin_exact_jit(
        rig, pose, binding, skin.make_style(tex, np.ones((3, 4))), styles="radial"
    )[0]
    centres = jax.vmap(lambda x: skin.spline_point(pose.points[0], 4.0, x))(binding.x[:, 0])
    r_plain = jnp.linalg.norm(plain - centres, axis=1)
    r_bulge = jnp.linalg.norm(bulge - centres, axis=1)
    assert bool(jnp.all(r_bulge >= r_plain - 1e-5)) and float(jnp.max(r_bulge - r_plain)) > 0.01
    # dominant-only equals all-influence styling for single-influence vertices
    dom = skin_exact_jit(
        rig,
        pose,
        binding,
        skin.make_style(tex, np.ones((3, 4))),
        styles="radial",
        dominant_only=True,
    )[0]
    np.testing.assert_allclose(dom, bulge, atol=_TIGHT)


# ---------------------------------------------------------------- rig hierarchy


def test_children_follow_parents():
    pts = np.array(
        [
            [[0, 0, 0], [0, 0, 1], [0, 0, 2]],
            [[0, 0, 2.5], [0, 1, 2.5], [0, 2, 2.5]],  # detached at bind: attach fixes it
        ],
        np.float32,
    )
    rig = skin.make_rig(pts, parent=[-1, 0], parent_point=[-1 + 1, 2][0:1] + [2])
    attached = skin.attach_children(rig, jnp.asarray(pts))
    np.testing.assert_allclose(attached[1, 0], attached[0, 2], atol=_TIGHT)
    rig2 = skin.make_rig(np.asarray(attached), parent=[-1, 0], parent_point=[0, 2])
    rot = skin.axis_angle_to_matrix(jnp.array([0.0, 0.5, 0.0]))
    pose = skin.forward_kinematics(rig2, jnp.stack([rot, jnp.eye(3)]), jnp.stack([rot, rot]))
    np.testing.assert_allclose(pose.points[1, 0], pose.points[0, 2], atol=1e-5)
    # segment lengths are kept
    lengths = jnp.linalg.norm(jnp.diff(pose.points, axis=1), axis=-1)
    bind_lengths = jnp.linalg.norm(jnp.diff(rig2.bind.points, axis=1), axis=-1)
    np.testing.assert_allclose(lengths, bind_lengths, atol=1e-5)


# ---------------------------------------------------------------- baselines


def test_lbs_and_dqs_of_rigid_pose_equal_rigid_transform():
    rng = np.random.default_rng(6)
    rot = np.asarray(skin.axis_angle_to_matrix(jnp.asarray(rng.normal(size=3), jnp.float32)))
    t = rng.normal(size=3)
    rigid = np.concatenate([rot, t[:, None]], axis=1).astype(np.float32)
    transforms = jnp.asarray(np.stack([rigid] * 4))
    v = rng.normal(size=(20, 3)).astype(np.float32)
    n = rng.normal(size=(20, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    joints = rng.integers(0, 4, (20, 3)).astype(np.int32)
    w = rng.random((20, 3)).astype(np.float32)
    w /= w.sum(1, keepdims=True)
    for fn in (lbs_jit, dqs_jit):
        pos, nrm = fn(transforms, v, n, joints, w)
        np.testing.assert_allclose(pos, v @ rot.T + t, atol=1e-5)
        np.testing.assert_allclose(nrm, n @ rot.T, atol=1e-5)
    # unit quaternions: q and -q blend to the same rigid transform (sign alignment)
    dual = skin.dual_quaternions(transforms[:, :3])
    np.testing.assert_allclose(jnp.linalg.norm(dual[:, :4], axis=1), 1.0, atol=1e-6)
    flipped = dual.at[1].multiply(-1.0)
    a = skin.dqs_vertex(dual, jnp.array([0, 1]), jnp.array([0.5, 0.5]), v[0], n[0])[0]
    b = skin.dqs_vertex(flipped, jnp.array([0, 1]), jnp.array([0.5, 0.5]), v[0], n[0])[0]
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_quaternion_roundtrip():
    rng = np.random.default_rng(7)
    for _ in range(20):
        aa = rng.normal(size=3) * 1.5
        rot = skin.axis_angle_to_matrix(jnp.asarray(aa, jnp.float32))
        q = skin.matrix_to_quaternion(rot)
        w, v = q[0], q[1:]
        p = jnp.array([0.3, -0.2, 0.9])
        rotated = p + 2 * jnp.cross(v, jnp.cross(v, p) + w * p)
        np.testing.assert_allclose(rotated, rot @ p, atol=1e-5)


def test_lbs_dqs_same_skeleton_candy_wrapper(limb):
    """Twist 180°: LBS collapses the joint cross-section, DQS and spline skinning do not."""
    rig, binding = limb
    pose = _bent_pose(rig, 0.0, twist=math.pi)
    transforms = bones_jit(rig, pose)
    joints, weights = skin.bone_weights_from_binding(binding)
    lbs = lbs_jit(transforms, binding.rest, binding.rest_normal, joints, weights)[0]
    dqs = dqs_jit(transforms, binding.rest, binding.rest_normal, joints, weights)[0]
    spl = skin_exact_jit(rig, pose, binding)[0]
    ring = np.abs(np.asarray(binding.x[:, 0]) - 0.5) < 1e-3
    assert ring.any()

    def radius(p):
        return np.linalg.norm(np.asarray(p)[ring][:, :2], axis=1).mean()

    assert radius(lbs) < 0.05  # candy wrapper: the 0.2 radius collapses
    assert radius(dqs) > 0.19 and radius(spl) > 0.19
    # the bone transforms reproduce the spline ends exactly
    ends = np.abs(np.asarray(binding.x[:, 0]) - 1.0) < 1e-4
    np.testing.assert_allclose(np.asarray(lbs)[ends], np.asarray(spl)[ends], atol=1e-4)


# ---------------------------------------------------------------- bad input


def _valid():
    rig = skin.make_rig(STRAIGHT)
    v, _ = _cylinder(4, 3)
    return rig, v


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(stiffness=1.5), "stiffness"),
        (dict(control_points=np.full((1, 3, 3), np.nan)), "control_points"),
        (dict(control_points=np.zeros((1, 3, 3))), "control_points"),
        (dict(reference_normal=[[0.0, 0.0, 1.0]]), "reference_normal"),
        (dict(parent=[1]), "parent"),
    ],
)
def test_make_rig_bad_input(kwargs, match):
    args = dict(control_points=STRAIGHT)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        skin.make_rig(args.pop("control_points"), **args)


def test_bind_bad_input():
    rig, v = _valid()
    nv = len(v)
    ones = np.ones((nv, 1))
    zeros = np.zeros((nv, 1), np.int32)
    with pytest.raises(ValueError, match="weights"):
        skin.bind_mesh(rig, v, zeros, -ones)
    with pytest.raises(ValueError, match="sum to one"):
        skin.bind_mesh(rig, v, zeros, 0.5 * ones)
    with pytest.raises(ValueError, match="spline_index"):
        skin.bind_mesh(rig, v, zeros + 1, ones)
    with pytest.raises(ValueError, match="spline_index"):
        skin.bind_mesh(rig, v, zeros[:-1], ones[:-1])
    with pytest.raises(ValueError, match="weights"):
        skin.bind_mesh(rig, v, zeros, ones[:-1])
    with pytest.raises(TypeError, match="spline_index"):
        skin.bind_mesh(rig, v, zeros.astype(float), ones)
    with pytest.raises(ValueError, match="vertices"):
        skin.bind_mesh(rig, np.full_like(v, np.inf), zeros, ones)
    with pytest.raises(ValueError, match="spline_index"):
        skin.bind_mesh(rig, v, np.zeros((nv, 4), np.int32), np.full((nv, 4), 0.25))


def test_style_and_pose_bad_input():
    with pytest.raises(ValueError, match="textures"):
        skin.make_style(np.ones((3, 4)), np.ones((3, 4)))
    with pytest.raises(ValueError, match="textures"):
        skin.make_style(-np.ones((3, 4, 4)), np.ones((3, 4)))
    with pytest.raises(ValueError, match="curves"):
        skin.make_style(np.ones((3, 4, 4)), np.ones((2, 4)))
    rig, _ = _valid()
    bad = skin.SplinePose(points=rig.bind.points, stiffness=jnp.array([1.0]), twist=jnp.zeros(1))
    with pytest.raises(ValueError, match="stiffness"):
        skin.validate_pose(rig, bad)
    bad = skin.SplinePose(
        points=rig.bind.points.at[0, 0, 0].set(jnp.nan),
        stiffness=jnp.array([4.0]),
        twist=jnp.zeros(1),
    )
    with pytest.raises(ValueError, match="points"):
        skin.validate_pose(rig, bad)
    with pytest.raises(ValueError, match="styles"):
        skin.skin_exact(rig, rig.bind, None, styles="wobbly")  # type: ignore[arg-type]
    _, v = _valid()
    binding = skin.bind_mesh(rig, v, np.zeros((len(v), 1), np.int32), np.ones((len(v), 1)))
    flat = skin.Style(textures=jnp.ones((3, 4)), curves=jnp.ones((3, 4)), hollow=jnp.float32(0))
    with pytest.raises(ValueError, match="textures"):
        skin.skin_exact(rig, rig.bind, binding, flat, styles="radial")
    with pytest.raises(ValueError, match="stiffness"):
        skin.skin_exact(
            rig, bad.__class__(rig.bind.points, jnp.array([1.0]), jnp.zeros(1)), binding
        )
    # pass 2 alone: the tables' shapes are checked before anything is traced
    prepared = skin.prepare_sampled(binding, 4)
    with pytest.raises(ValueError, match="skinning"):
        skin.skin_sampled_tables(jnp.zeros((5, 24)), jnp.zeros((5, 20)), prepared, samples=4)
    with pytest.raises(ValueError, match="style_table"):
        skin.skin_sampled_tables(jnp.zeros((4, 24)), jnp.zeros((4, 9)), prepared, samples=4)
    with pytest.raises(ValueError, match="style is required"):
        skin.skin_sampled_tables(
            jnp.zeros((4, 24)), jnp.zeros((4, 20)), prepared, samples=4, styles="both"
        )
    with pytest.raises(TypeError, match="SampledBinding"):
        skin.skin_sampled_tables(jnp.zeros((4, 24)), jnp.zeros((4, 20)), binding, samples=4)
    with pytest.raises(ValueError, match="joints"):
        skin.linear_blend_skinning(
            jnp.zeros((2, 3, 4)),
            jnp.zeros((3, 3)),
            jnp.zeros((3, 3)),
            jnp.full((3, 1), 5, jnp.int32),
            jnp.ones((3, 1)),
        )


def test_sampled_styles_match_exact_dominant_only():
    """Two chained splines, blended weights: sampled + style on the dominant spline ≈ exact."""
    pts = np.array(
        [[[0, 0, 0], [0, 0, 1], [0, 0, 2]], [[0, 0, 2], [0, 0, 3], [0, 0, 4]]], np.float32
    )
    rig = skin.make_rig(
        pts, reference_normal=[[1, 0, 0], [1, 0, 0]], parent=[-1, 0], parent_point=[0, 2]
    )
    v, n = _cylinder(10, 21, length=4.0)
    t = np.clip((v[:, 2] - 1.6) / 0.8, 0, 1)
    idx = np.stack([np.zeros(len(v)), np.ones(len(v))], 1).astype(np.int32)
    w = np.stack([1 - t, t], 1)
    binding = skin.bind_mesh(rig, v, idx, w, normals=n)
    rot = jnp.stack([skin.axis_angle_to_matrix(jnp.array([a, 0.0, 0.0])) for a in (0.6, 0.9)])
    pose = skin.forward_kinematics(rig, rot, rot, twist=jnp.array([0.5, -1.0]))
    rng = np.random.default_rng(8)
    style = skin.make_style(
        0.7 + 0.6 * rng.random((3, 6, 8)), 0.8 + 0.4 * rng.random((3, 8)), hollow=0.05
    )
    for styles in ("both",):
        exact = skin_exact_jit(rig, pose, binding, style, styles=styles, dominant_only=True)
        sampled = skin_sampled_jit(rig, pose, binding, style, styles=styles, samples=64)
        assert float(jnp.max(jnp.abs(exact[0] - sampled[0]))) < _SAMPLED_TOL * 4.0
        assert float(jnp.max(jnp.abs(exact[1] - sampled[1]))) < 2e-2
    # identity style adds exactly nothing on the sampled path
    ident = skin.identity_style((6, 8), 8)
    a = skin_sampled_jit(rig, pose, binding, ident, styles="both", samples=64)[0]
    b = skin_sampled_jit(rig, pose, binding, ident, samples=64)[0]
    np.testing.assert_allclose(a, b, atol=_TIGHT)


# ---------------------------------------------------------------- real asset (fox.glb)


def test_fox_bind_pose_lbs_returns_bind_mesh(data_dir):
    fox = skin.load_gltf_skin(data_dir / "rigs" / "fox.glb")
    assert fox.vertices.shape == (1728, 3) and fox.joints.shape == (1728, 4)
    assert len(fox.joint_names) == 23
    np.testing.assert_allclose(fox.weights.sum(1), 1.0, atol=1e-6)
    mats = skin.joint_matrices(fox, fox.rest_trs)
    pos, nrm = lbs_jit(jnp.asarray(mats), fox.vertices, fox.normals, fox.joints, fox.weights)
    size = float(np.linalg.norm(fox.vertices.max(0) - fox.vertices.min(0)))
    # the Blender re-export's rest TRS and inverse bind matrices agree to about 0.1 % of the size
    assert float(np.abs(np.asarray(pos) - fox.vertices).max()) < 5e-3 * size
    # an animated frame moves the mesh, stays finite
    anim = skin.joint_matrices(fox, skin.sample_animation(fox, 0.7))
    moved = lbs_jit(jnp.asarray(anim), fox.vertices, fox.normals, fox.joints, fox.weights)[0]
    assert bool(jnp.all(jnp.isfinite(moved))) and float(jnp.abs(moved - pos).max()) > 1e-3 * size


def test_gltf_bad_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="path"):
        skin.load_gltf_skin(tmp_path / "missing.glb")


def test_cli_skin_writes_image(tmp_path, capsys):
    import imageio.v3 as iio

    from jaxgfx.cli import main

    argv = ["skin", "--method", "dqs", "--bend", "60", "--size", "24x20", "--out", str(tmp_path)]
    assert main(argv) == 0
    img = iio.imread(tmp_path / "skin.png")
    assert img.shape == (20, 24, 3) and img.min() < 250  # something was drawn
    # --out naming a .png writes that file, as the other commands do
    assert main(argv[:-1] + [str(tmp_path / "arm.png")]) == 0
    assert np.array_equal(iio.imread(tmp_path / "arm.png"), img)
    assert main(["skin", "--size", "0x3", "--out", str(tmp_path)]) == 2
    assert "error: argument --size" in capsys.readouterr().err


def test_hollow_scales_about_displaced_origin():
    """Fig. 5.23: with a hollow offset h the envelope scales about (0, h) in spline space."""
    style = skin.make_style(np.full((3, 2, 2), 0.5), np.ones((3, 2)), hollow=0.3)
    # full twist weight (|γ|/π = 1) makes S_rs the texture value 0.5 (Eq. 5.9)
    out, _ = skin.apply_style(
        style, jnp.array([0.1, 0.5, 0.2]), jnp.zeros(3), 0.4, 0.0, 1.0, radial=True, rect=False
    )
    np.testing.assert_allclose(out, [0.05, 0.3 + 0.5 * 0.2, 0.2], atol=1e-6)
    fixed, _ = skin.apply_style(style, jnp.array([0.0, 0.3, 0.0]), jnp.zeros(3), 0.4, 0.0, 1.0)
    np.testing.assert_allclose(fixed, [0.0, 0.3, 0.0], atol=1e-6)


def test_limb_mesh_closed_and_outward():
    import trimesh

    v, n, f = skin.limb_mesh(12, 9, 0.2, 2.0)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.volume > 0  # outward faces
    assert np.all(np.abs(np.linalg.norm(n, axis=1) - 1) < 1e-6)


# ---------------------------------------------------------------- fast kernels vs per-vertex


_KERNEL_RTOL = 1e-5  # structure-of-arrays kernels vs the per-vertex references (float32 rounding)
_KERNEL_ATOL = 2e-5


def _random_influences(rng, v: int, i: int, rows: int):
    joints = rng.integers(0, rows, (v, i)).astype(np.int32)
    weights = rng.random((v, i)).astype(np.float32)
    weights /= weights.sum(1, keepdims=True)
    verts = rng.normal(size=(v, 3)).astype(np.float32)
    normals = rng.normal(size=(v, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return joints, weights, verts, normals


@pytest.mark.parametrize("influences", [1, 4])
def test_lbs_kernel_equals_per_vertex_reference(influences):
    rng = np.random.default_rng(11)
    transforms = jnp.asarray(rng.normal(size=(5, 3, 4)).astype(np.float32))
    joints, weights, v, n = _random_influences(rng, 37, influences, 5)
    pos, nrm = lbs_jit(transforms, v, n, joints, weights)
    ref = jax.jit(jax.vmap(skin.lbs_vertex, in_axes=(None, 0, 0, 0, 0)))
    rpos, rnrm = ref(transforms, joints, weights, v, n)
    np.testing.assert_allclose(pos, rpos, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
    np.testing.assert_allclose(nrm, rnrm, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
    # vmap over characters equals a loop over them
    batch = jnp.stack([transforms, 0.5 * transforms, -transforms])
    bpos, bnrm = jax.jit(jax.vmap(skin.linear_blend_skinning, in_axes=(0, None, None, None, None)))(
        batch, v, n, joints, weights
    )
    for k in range(3):
        lpos, lnrm = lbs_jit(batch[k], v, n, joints, weights)
        np.testing.assert_allclose(bpos[k], lpos, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
        np.testing.assert_allclose(bnrm[k], lnrm, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)


def test_lbs_and_dqs_gradients_are_the_per_vertex_references():
    # Reverse mode through the mesh kernels (their CPU batching rule has none of its own):
    # gradients w.r.t. the bone transforms and the bind vertices equal those through
    # lbs_vertex / dqs_vertex vmapped over the vertices, and a central finite difference
    # along a random direction; vmap over poses of the gradient equals a loop.
    rng = np.random.default_rng(17)
    axes = jnp.asarray(rng.normal(size=(4, 3)), jnp.float32)
    transforms = jnp.concatenate(
        [
            jax.vmap(skin.axis_angle_to_matrix)(axes),
            jnp.asarray(rng.normal(size=(4, 3, 1)), jnp.float32),
        ],
        -1,
    )
    joints, weights, v, n = _random_influences(rng, 23, 3, 4)
    per_vertex = {
        "lbs": lambda t, v: jax.vmap(skin.lbs_vertex, (None, 0, 0, 0, 0))(t, joints, weights, v, n),
        "dqs": lambda t, v: jax.vmap(skin.dqs_vertex, (None, 0, 0, 0, 0))(
            skin.dual_quaternions(t), joints, weights, v, n
        ),
    }
    kernels = {"lbs": skin.linear_blend_skinning, "dqs": skin.dual_quaternion_skinning}
    direction = jnp.asarray(rng.normal(size=transforms.shape), jnp.float32)

    def loss(t, v, skin_fn):
        pos, nrm = skin_fn(t, v)
        return jnp.sum(pos**2) + jnp.sum(jnp.sin(3.0 * nrm))

    for name, kernel in kernels.items():
        mesh_fn = functools.partial(_skin_mesh, kernel, n, joints, weights)
        ours = jax.jit(jax.grad(lambda t, v, fn=mesh_fn: loss(t, v, fn), (0, 1)))
        ref = jax.jit(jax.grad(lambda t, v, fn=per_vertex[name]: loss(t, v, fn), (0, 1)))
        g_t, g_v = ours(transforms, v)
        r_t, r_v = ref(transforms, v)
        np.testing.assert_allclose(g_t, r_t, rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(g_v, r_v, rtol=1e-4, atol=1e-4)
        t64, d64, h = np.asarray(transforms, np.float64), np.asarray(direction, np.float64), 1e-3
        f = functools.partial(_loss_at, loss, v, per_vertex[name])
        fd = (f(t64 + h * d64) - f(t64 - h * d64)) / (2 * h)
        assert abs(float(jnp.sum(g_t * direction)) - fd) <= 2e-2 * max(1.0, abs(fd)), name
        poses = jnp.stack([transforms, transforms.at[:, :, 3].multiply(0.5)])
        batched = jax.vmap(ours, (0, None))(poses, v)[0]
        np.testing.assert_allclose(batched[1], ours(poses[1], v)[0], rtol=1e-5, atol=1e-5)


def _skin_mesh(kernel, normals, joints, weights, transforms, vertices):
    return kernel(transforms, vertices, normals, joints, weights)


def _loss_at(loss, vertices, skin_fn, transforms) -> float:
    return float(loss(jnp.asarray(transforms, jnp.float32), vertices, skin_fn))


def test_dqs_kernel_equals_per_vertex_reference():
    # The structure-of-arrays DQS equals dqs_vertex vmapped over the vertices, with
    # rotations far apart (quaternions in opposite hemispheres get flipped to the dominant
    # influence's), and a batch of 11 poses (more than one chunk) equals a loop.
    rng = np.random.default_rng(13)
    axes = rng.normal(size=(6, 3)) * np.array([[2.5], [2.8], [0.3], [3.0], [1.0], [0.1]])
    rot = jax.vmap(skin.axis_angle_to_matrix)(jnp.asarray(axes, jnp.float32))
    transforms = jnp.concatenate([rot, jnp.asarray(rng.normal(size=(6, 3, 1)), jnp.float32)], -1)
    dual = skin.dual_quaternions(transforms)
    assert np.any(np.asarray(dual[:, :4] @ dual[:, :4].T) < 0)  # antipodal pairs present
    joints, weights, v, n = _random_influences(rng, 53, 4, 6)
    pos, nrm = jax.jit(skin.dual_quaternion_skinning)(transforms, v, n, joints, weights)
    ref = jax.jit(jax.vmap(skin.dqs_vertex, in_axes=(None, 0, 0, 0, 0)))
    rpos, rnrm = ref(dual, joints, weights, v, n)
    np.testing.assert_allclose(pos, rpos, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
    np.testing.assert_allclose(nrm, rnrm, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
    batch = (
        jnp.stack([transforms] * 11)
        .at[:, :, :, 3]
        .multiply(jnp.linspace(0.5, 1.5, 11)[:, None, None])
    )
    bpos, _ = jax.jit(jax.vmap(skin.dual_quaternion_skinning, in_axes=(0, None, None, None, None)))(
        batch, v, n, joints, weights
    )
    for k in (0, 8, 10):
        lpos, _ = skin.dual_quaternion_skinning(batch[k], v, n, joints, weights)
        np.testing.assert_allclose(bpos[k], lpos, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)


def _raw_sampled_normals(table, coord, weights, normals):
    """NumPy: the blended normal of skin_vertex_sampled before normalizing, (V, 3)."""
    table = np.asarray(table, np.float64)
    r0 = np.floor(coord)
    rows = table[r0.astype(np.int64)]  # (V, I, 24)
    m = np.einsum("vi,vic->vc", weights, rows[..., :12] + (coord - r0)[..., None] * rows[..., 12:])
    return np.einsum("vkj,vk->vj", m[:, :9].reshape(-1, 3, 3), normals)


def test_sampled_kernel_equals_per_vertex_reference():
    rng = np.random.default_rng(12)
    samples = 8
    rig = skin.make_rig(
        np.cumsum(rng.normal(size=(2, 3, 3)), axis=1).astype(np.float32) + [[[0, 0, 0]]],
        stiffness=4.0,
    )
    nv = 29
    v = rng.normal(size=(nv, 3)).astype(np.float32)
    coord = rng.random((nv, 3)).astype(np.float32) * (samples - 1) + samples * rng.integers(
        0, 2, (nv, 3)
    ).astype(np.float32)
    coord[0, 0] = samples - 1.0  # the very end of the first spline
    _, weights, _, n = _random_influences(rng, nv, 3, 2)
    prepared = skin.SampledBinding(
        coord=jnp.asarray(coord),
        weight=jnp.asarray(weights),
        rest=jnp.asarray(v),
        rest_normal=jnp.asarray(n),
        dominant_coord=jnp.asarray(coord[:, 0]),
        dominant_weight=jnp.asarray(weights[:, 0]),
        dominant_local=jnp.asarray(v),
        dominant_local_normal=jnp.asarray(n),
    )
    poses = [skin.bind_pose(rig)] + [
        skin.forward_kinematics(
            rig,
            jnp.eye(3)[None],
            skin.axis_angle_to_matrix(jnp.asarray(rng.normal(size=3), jnp.float32))[None],
        )
        for _ in range(2)
    ]
    table_fn = jax.jit(skin.sample_spline_frames, static_argnames="samples")
    ref = jax.jit(jax.vmap(skin.skin_vertex_sampled, in_axes=(None, 0, 0, 0, 0)))
    style = skin.make_style(0.5 + rng.random((3, 6, 5)), 0.5 + rng.random((3, 7)), hollow=0.05)
    style_ref = jax.jit(
        lambda st, style, b: jax.vmap(
            lambda u, w, lv, ln: skin.style_offset_sampled(st, style, samples, u, w, lv, ln)
        )(b.dominant_coord, b.dominant_weight, b.dominant_local, b.dominant_local_normal)
    )
    outs, rounding_moved = [], []
    for pose in poses:
        table, _ = table_fn(rig, pose, samples=samples)
        pos, nrm = _skin_sampled_jit(rig, pose, prepared, None, samples=samples, styles="none")
        rpos, rnrm = ref(
            table, prepared.coord, prepared.weight, prepared.rest, prepared.rest_normal
        )
        np.testing.assert_allclose(pos, rpos, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
        np.testing.assert_allclose(nrm, rnrm, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
        outs.append((pos, nrm))
        # sub-rows (blend and style offsets): the LBS kernel on the expanded tables = the
        # references at u rounded to 1/4 (one compile, styled)
        spos_q, snrm_q = _skin_sampled_jit(
            rig, pose, prepared, style, samples=samples, styles="both", subrows=4
        )
        qref = ref(
            table, np.round(coord * 4) / 4, prepared.weight, prepared.rest, prepared.rest_normal
        )
        rounded = prepared._replace(dominant_coord=np.round(coord[:, 0] * 4) / 4)
        dpos_q, dnrm_q = style_ref(table_fn(rig, pose, samples=samples)[1], style, rounded)
        np.testing.assert_allclose(spos_q, qref[0] + dpos_q, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
        # the normal offset joins the raw blend, normalized once (Eq. 5.13, as skin_exact)
        ref_nq = _raw_sampled_normals(table, np.round(coord * 4) / 4, weights, n) + dnrm_q
        ref_nq /= np.linalg.norm(ref_nq, axis=-1, keepdims=True)
        np.testing.assert_allclose(snrm_q, ref_nq, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
        # the style kernel equals the vmapped style_offset_sampled (both envelopes, hollow)
        spos, snrm = _skin_sampled_jit(rig, pose, prepared, style, samples=samples, styles="both")
        dpos, dnrm = style_ref(table_fn(rig, pose, samples=samples)[1], style, prepared)
        np.testing.assert_allclose(spos, rpos + dpos, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
        ref_n = _raw_sampled_normals(table, coord, weights, n) + dnrm
        ref_n /= np.linalg.norm(ref_n, axis=-1, keepdims=True)
        np.testing.assert_allclose(snrm, ref_n, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
        assert float(np.abs(dpos).max()) > 1e-3  # the style moved the vertices
        rounding_moved.append(float(np.abs(spos_q - spos).max()))
    assert max(rounding_moved) > 1e-4  # rounding u is not a no-op (it is at the bind pose)
    # vmap over characters (poses) equals the loop
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *poses)
    bpos, bnrm = jax.jit(
        jax.vmap(
            lambda p: skin.skin_sampled(rig, p, prepared, samples=samples),
        )
    )(stacked)
    for k, (pos, nrm) in enumerate(outs):
        np.testing.assert_allclose(bpos[k], pos, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)
        np.testing.assert_allclose(bnrm[k], nrm, rtol=_KERNEL_RTOL, atol=_KERNEL_ATOL)


def test_an_eager_call_compiles_one_program_and_keeps_its_errors(compile_counter):
    # Outside jit the mesh kernels run as one compiled program per shapes (op by op,
    # each of their operations compiled on its own, dozens at every new mesh size), give
    # the jitted call's result, and still refuse bad values before compiling.
    rng = np.random.default_rng(5)
    joints, weights, v, n = _random_influences(rng, 29, 3, 4)
    axes = rng.normal(size=(4, 3)).astype(np.float32)
    rot = np.stack([np.asarray(skin.axis_angle_to_matrix(a)) for a in axes])
    t = np.concatenate([rot, rng.normal(size=(4, 3, 1)).astype(np.float32)], -1)
    for kernel in (skin.linear_blend_skinning, skin.dual_quaternion_skinning):
        with compile_counter() as counter:
            pos, nrm = kernel(t, v, n, joints, weights)
        assert counter.count == 1, (kernel.__name__, counter.count)
        jpos, jnrm = jax.jit(kernel)(t, v, n, joints, weights)
        np.testing.assert_allclose(pos, jpos, rtol=1e-6, atol=1e-6)
        bad = v.copy()
        bad[3, 1] = np.nan
        with pytest.raises(ValueError, match="vertices: 1 of 87 values are NaN"):
            kernel(t, bad, n, joints, weights)
