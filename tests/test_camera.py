"""Camera: projection identities, batching, degenerate views, bad input."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgfx.camera import (
    Camera,
    c2w_from_camera,
    camera_basis,
    camera_from_c2w,
    camera_from_degrees,
    camera_from_opencv,
    camera_matrix,
    camera_to_screen,
    intrinsics_matrix,
    look_at,
    opencv_from_camera,
    orbit_cameras,
    pixel_rays,
    project,
    rotation_matrix,
    rotation_quaternion,
    screen_to_camera,
    stack_cameras,
    supersampled,
    validate_camera,
    view_matrix,
    yaw_pitch_roll,
    yaw_pitch_roll_rotation,
)

TOL = 1e-4

CAMS = [
    dict(position=[1.0, 2.0, -3.0], yaw=30.0, pitch=-20.0, roll=0.0),
    dict(position=[0.0, 0.0, 0.0], yaw=-135.0, pitch=45.0, roll=10.0),
    dict(position=[5.0, 10.0, 5.0], yaw=0.0, pitch=-90.0, roll=0.0),  # straight down
    dict(position=[0.0, 1.0, 0.0], yaw=0.0, pitch=90.0, roll=0.0),  # straight up
]


@pytest.mark.parametrize("kw", CAMS)
def test_basis_orthonormal_and_right_handed_screen(kw):
    cam = camera_from_degrees(width=32, height=24, **kw)
    r, u, f = (np.asarray(v) for v in camera_basis(cam))
    m = np.stack([r, u, f])
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=TOL)
    assert np.all(np.isfinite(m))
    # x right, y up, z forward is a left-handed frame in a right-handed world.
    np.testing.assert_allclose(np.cross(r, u), -f, atol=TOL)


def test_conventions_yaw_pitch():
    cam = camera_from_degrees([0, 0, 0], yaw=0.0, pitch=0.0)
    np.testing.assert_allclose(camera_basis(cam)[2], [0, 0, 1], atol=1e-6)
    cam = camera_from_degrees([0, 0, 0], yaw=90.0, pitch=0.0)
    np.testing.assert_allclose(camera_basis(cam)[2], [1, 0, 0], atol=1e-6)
    cam = camera_from_degrees([0, 0, 0], yaw=0.0, pitch=30.0)
    assert float(camera_basis(cam)[2][1]) > 0.49  # positive pitch looks up
    # A point up and ahead lands in the upper half of the image (row < H/2).
    xy, depth = project(
        camera_from_degrees([0, 0, 0], width=64, height=48), jnp.array([0.0, 1.0, 5.0])
    )
    assert float(xy[1]) < 24 and float(depth) == pytest.approx(5.0)


@pytest.mark.parametrize("aa", [(1, 1), (2, 1)])
@pytest.mark.parametrize("kw", CAMS)
def test_pixel_rays_project_back_to_pixel_centres(kw, aa):
    cam = supersampled(camera_from_degrees(width=8, height=12, **kw), aa)
    o, d = pixel_rays(cam, normalize=False)
    pts = o + 7.0 * d  # depth 7 along the view axis when not normalised
    xy, depth = project(cam, pts.reshape(-1, 3))
    jj, ii = np.meshgrid(np.arange(12), np.arange(8 * aa[0]), indexing="ij")
    expect = np.stack([ii + 0.5, jj + 0.5], -1).reshape(-1, 2)
    np.testing.assert_allclose(xy, expect, atol=1e-3)
    np.testing.assert_allclose(depth, 7.0, rtol=1e-5)


@pytest.mark.parametrize("aa", [(1, 1), (2, 1)])
def test_camera_matrix_matches_project(aa):
    cam = supersampled(camera_from_degrees([1, 2, 3], 20, -10, 5, 50, 40, 30, 0.1, 100.0), aa)
    pts = jnp.array([[2.0, 1.5, 9.0], [0.0, 2.0, 6.0]])
    clip = jnp.concatenate([pts, jnp.ones((2, 1))], 1) @ camera_matrix(cam).T
    ndc = clip[:, :3] / clip[:, 3:]
    xy, depth = project(cam, pts)
    px = (ndc[:, 0] + 1) * 0.5 * cam.width
    py = (1 - ndc[:, 1]) * 0.5 * cam.height
    np.testing.assert_allclose(np.stack([px, py], -1), xy, atol=1e-3)
    np.testing.assert_allclose(clip[:, 3], depth, rtol=1e-5)
    v = view_matrix(cam)
    np.testing.assert_allclose(v[:3, :3] @ v[:3, :3].T, np.eye(3), atol=TOL)


@pytest.mark.parametrize("aa", [(1, 1), (2, 1)])
def test_screen_to_camera_inverts_camera_to_screen(aa):
    cam = supersampled(camera_from_degrees([0, 0, 0], 0, 0, 0, 50, 40, 30), aa)
    p = jnp.array([[0.3, -0.2, 2.0], [-1.0, 0.5, 4.0], [0.0, 0.0, 1.0]])
    sx, sy = np.asarray(camera_to_screen(cam, p)).T
    rx, ry = screen_to_camera(cam, sx, sy)
    np.testing.assert_allclose(np.stack([rx, ry], -1), p[:, :2] / p[:, 2:], atol=1e-5)


@pytest.mark.parametrize("aa", [(2, 1), (2, 2), (3, 2)])
def test_supersampled_sees_the_same_view(aa):
    # The finer grid covers the same view: every point lands on the same spot
    # in units of the original pixels, so antialias() gives back that image.
    cam = camera_from_degrees([1, 2, 3], 20, -10, 5, 50, 40, 30)
    fine = supersampled(cam, aa)
    assert (fine.width, fine.height) == (40 * aa[0], 30 * aa[1])
    assert fine.pixel_aspect == pytest.approx(aa[1] / aa[0])
    pts = jnp.array([[2.0, 1.5, 9.0], [0.0, 2.0, 6.0], [1.0, 2.0, 3.5]])
    xy, d = project(cam, pts)
    xy_f, d_f = project(fine, pts)
    np.testing.assert_allclose(xy_f / np.asarray(aa, np.float32), xy, atol=1e-3)
    np.testing.assert_allclose(d_f, d, rtol=1e-6)
    # Corner rays of the fine grid sit a fine half-pixel inside the original corners.
    _, dirs = pixel_rays(fine, normalize=False)
    xy_c, _ = project(fine, fine.position + dirs[0, 0])
    np.testing.assert_allclose(xy_c, [0.5, 0.5], atol=1e-3)
    same = supersampled(fine, (1, 1))
    assert same.shape == fine.shape
    for a, b in zip(jax.tree_util.tree_leaves(same), jax.tree_util.tree_leaves(fine)):
        np.testing.assert_array_equal(a, b)


def test_look_at_straight_down_and_up_finite():
    cam = look_at([0, 10, 0], [0, 0, 0], width=8, height=8)
    f = np.asarray(camera_basis(cam)[2])
    np.testing.assert_allclose(f, [0, -1, 0], atol=1e-6)
    cam = look_at([0, 0, 0], [0, 5, 0], width=8, height=8)
    assert np.all(np.isfinite(np.asarray(pixel_rays(cam)[1])))


def test_jit_and_vmap_agree_with_loop():
    cams = orbit_cameras([0, 0, 0], 5.0, 5, width=8, height=6)
    pts = jnp.array([[0.3, 0.2, -0.1], [1.0, -1.0, 0.5]])
    batched = jax.jit(jax.vmap(project, in_axes=(0, None)))(cams, pts)
    for k in range(5):
        one = jax.tree_util.tree_map(lambda x, k=k: x[k], cams)
        xy, d = project(one, pts)
        np.testing.assert_allclose(batched[0][k], xy, atol=1e-4)
        np.testing.assert_allclose(batched[1][k], d, atol=1e-5)
    # every orbit camera looks at the centre: it projects to the image centre
    c = jax.vmap(project, in_axes=(0, None))(cams, jnp.zeros(3))
    np.testing.assert_allclose(c[0], np.tile([4.0, 3.0], (5, 1)), atol=1e-3)
    np.testing.assert_allclose(c[1], 5.0, rtol=1e-5)


def test_camera_is_pytree_with_static_resolution():
    cam = camera_from_degrees([0, 0, 0], width=10, height=7)
    leaves, tree = jax.tree_util.tree_flatten(cam)
    assert len(leaves) == 6
    back = jax.tree_util.tree_unflatten(tree, leaves)
    assert isinstance(back, Camera) and back.shape == (7, 10)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(width=0), "width"),
        (dict(height=-3), "height"),
        (dict(width=2.5), "width"),
        (dict(fov=0.0), r"fov must be in \(0, 180\) degrees"),
        (dict(fov=180.0), r"fov must be in \(0, 180\) degrees"),
        (dict(near=0.0), "near"),
        (dict(near=2.0, far=1.0), "far"),
        (dict(position=[0, math.nan, 0]), "position"),
        (dict(position=[0, 0]), "position"),
        (dict(principal=[1.0, math.inf]), "principal"),
        (dict(focal=[0.0, 2.0]), "focal"),
        (dict(focal=[1.0, 2.0, 3.0]), "focal"),
        (dict(focal="wide"), "focal"),
        (dict(rotation=[0.0, 0.0, 0.0, 0.0]), "rotation"),
        (dict(rotation=[1.0, 0.0, 0.0]), "rotation"),
    ],
)
def test_bad_camera_input(kw, match):
    args = dict(position=[0, 0, 0])
    args.update(kw)
    fields = {k: args.pop(k) for k in ("focal", "rotation") if k in args}
    with pytest.raises((ValueError, TypeError), match=match):
        cam = camera_from_degrees(**args)
        validate_camera(dataclasses.replace(cam, **fields))


@pytest.mark.parametrize("factor", [(0, 1), (2, -1), (2,), "2x1"])
def test_bad_supersample_factor(factor):
    with pytest.raises((ValueError, TypeError), match="factor"):
        supersampled(camera_from_degrees([0, 0, 0], width=4, height=4), factor)


def test_stack_rejects_mixed_resolution():
    with pytest.raises(ValueError, match="width, height"):
        stack_cameras(
            [camera_from_degrees([0, 0, 0], width=4), camera_from_degrees([0, 0, 0], width=5)]
        )
    with pytest.raises(ValueError, match="distinct"):
        look_at([1, 1, 1], [1, 1, 1])


@pytest.mark.parametrize("kw", CAMS)
def test_world_to_camera_matches_rotation_matrix(kw):
    # world_to_camera (multiply-adds) and its (3, V) layout against the rotation matrix
    # of the basis in float64 NumPy.
    from jaxgfx._src.camera import world_to_camera, world_to_camera_soa

    cam = camera_from_degrees(width=32, height=24, **kw)
    pts = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32) * 10
    rot = np.stack([np.asarray(v, np.float64) for v in camera_basis(cam)])
    ref = (pts - np.asarray(cam.position, np.float64)) @ rot.T
    np.testing.assert_allclose(world_to_camera(cam, pts), ref, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(
        world_to_camera_soa(cam, jnp.asarray(pts)), ref.T, rtol=1e-5, atol=1e-4
    )


def test_pixel_rays_are_the_same_bits_in_a_vmapped_batch():
    # The renderers' batches (a vmapped program over cameras) must see the rays a
    # lone frame sees: XLA rewrote a division by the focal length as a product
    # with its reciprocal in the batch's program only, which moved the ray caster's
    # depths by a few ulps on some pixels and by a voxel on others.
    cams = [
        camera_from_degrees([3.0 * k, 5.0, -14.0], 30.0 * k, -10.0, 0.0, 50.0 + k, 96, 72)
        for k in range(4)
    ]
    one = jax.jit(lambda c: pixel_rays(c, normalize=False))
    batch = jax.jit(jax.vmap(lambda c: pixel_rays(c, normalize=False)))(stack_cameras(cams))
    for k, cam in enumerate(cams):
        for a, b in zip(one(cam), batch):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b[k]))


# ----------------------------------------------------------------------------------------------
# cameras from other conventions, and the rotation
# ----------------------------------------------------------------------------------------------


def _euler_basis(yaw, pitch, roll):
    """The yaw/pitch/roll convention's axes, written from its definition in float64."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    forward = np.array([sy * cp, sp, cy * cp])
    right0, up0 = np.array([-cy, 0.0, sy]), np.array([-sy * sp, cp, -cy * sp])
    return cr * right0 - sr * up0, sr * right0 + cr * up0, forward


def test_the_quaternion_holds_the_yaw_pitch_roll_convention():
    rng = np.random.default_rng(0)
    for yaw, pitch, roll in rng.uniform([-3, -1.5, -3], [3, 1.5, 3], (20, 3)):
        cam = camera_from_degrees([1, 2, 3], *(math.degrees(a) for a in (yaw, pitch, roll)))
        for got, want in zip(camera_basis(cam), _euler_basis(yaw, pitch, roll)):
            np.testing.assert_allclose(np.asarray(got), want, atol=1e-6)
        back = np.array([float(a) for a in yaw_pitch_roll(cam)])
        np.testing.assert_allclose(back, [yaw, pitch, roll], atol=2e-5)
        # the traced constructor is the NumPy one
        q = yaw_pitch_roll_rotation(jnp.float32(yaw), jnp.float32(pitch), jnp.float32(roll))
        np.testing.assert_allclose(np.asarray(q), np.asarray(cam.rotation), atol=1e-6)
    # rotation_quaternion inverts rotation_matrix, half turns included (w >= 0)
    for q in [*rng.normal(size=(20, 4)), [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.6, 0.8]]:
        q = np.asarray(q) / np.linalg.norm(q) * np.sign(q[0] if q[0] else 1.0)
        back = np.asarray(rotation_quaternion(rotation_matrix(jnp.asarray(q, jnp.float32))))
        np.testing.assert_allclose(back, q, atol=2e-6)


def test_euler_angles_lock_where_the_quaternion_does_not():
    # Looking straight down, yaw and roll turn the view about the same axis: the angles'
    # Jacobian has rank 2 (gimbal lock), the quaternion's tangent space keeps all three.
    def turn_rates(pitch):
        jac = jax.jacfwd(lambda a: rotation_matrix(yaw_pitch_roll_rotation(*a)))
        d = np.asarray(jac(jnp.array([0.3, pitch, 0.0], jnp.float64)), np.float64)
        return np.linalg.svd(d.reshape(9, 3), compute_uv=False)

    with jax.enable_x64(True):
        assert turn_rates(-0.4)[-1] > 0.5
        assert turn_rates(-math.pi / 2)[-1] < 1e-12
        q = jnp.asarray(yaw_pitch_roll_rotation(0.3, -math.pi / 2, 0.0), jnp.float64)
        jq = jax.jacfwd(rotation_matrix)(q).reshape(9, 4)
        assert np.linalg.svd(np.asarray(jq), compute_uv=False)[2] > 0.5


def _colmap_camera(width=64, height=48):
    """A COLMAP-like K (fx != fy, principal point off centre) and a world-to-camera pose."""
    from experiments.camera_models import opencv_intrinsics, opencv_look_at

    R, t = opencv_look_at([2.0, 1.5, -4.0], [0.2, -0.1, 0.3], roll=14.0)
    return opencv_intrinsics(width, height), R, t


def test_opencv_and_opengl_cameras_convert_exactly():
    from experiments.camera_models import round_trips

    K, R, t = _colmap_camera()
    cam = camera_from_opencv(K, R, t, 64, 48)
    pts = np.random.default_rng(1).normal(size=(30, 3)) * 0.8
    xy, depth = project(cam, jnp.asarray(pts, jnp.float32))
    h = (pts @ R.T + t) @ K.T
    np.testing.assert_allclose(np.asarray(xy), h[:, :2] / h[:, 2:], atol=2e-4)
    np.testing.assert_allclose(np.asarray(depth), h[:, 2], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(intrinsics_matrix(cam)), K, rtol=1e-7)
    errors = round_trips()
    assert max(errors.values()) < 1e-6, errors
    # NeRF's transforms.json: camera_angle_x and an OpenGL camera-to-world matrix
    c2w = np.array([[0, -1, 0, 0.5], [0, 0, 1, 4.0], [-1, 0, 0, 0.2], [0, 0, 0, 1]], float)
    f = 0.5 * 64 / math.tan(0.6 / 2)
    nerf = camera_from_c2w(c2w, [[f, 0, 32], [0, f, 24], [0, 0, 1]], 64, 48)
    right, up, forward = (np.asarray(b) for b in camera_basis(nerf))
    np.testing.assert_allclose(np.stack([right, up, -forward], 1), c2w[:3, :3], atol=1e-7)
    np.testing.assert_allclose(float(2 * np.arctan(32 / nerf.focal[0])), 0.6, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(c2w_from_camera(nerf)), c2w, atol=1e-6)
    K2, R2, t2 = opencv_from_camera(cam)
    np.testing.assert_allclose(np.asarray(R2), R, atol=1e-6)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(K=[[50, 1, 32], [0, 50, 24], [0, 0, 1]]), "skew"),
        (dict(K=[[-50, 0, 32], [0, 50, 24], [0, 0, 1]]), "focal lengths"),
        (dict(K=np.eye(2)), "K must have shape"),
        (dict(R=np.diag([1.0, 1.0, -1.0])), "rotation matrix"),
        (dict(R=np.eye(3) * 2), "rotation matrix"),
        (dict(t=[0.0, math.nan, 1.0]), "t must be finite"),
    ],
)
def test_bad_opencv_cameras_are_refused(kw, match):
    K, R, t = _colmap_camera()
    args = dict(K=K, R=R, t=t) | kw
    with pytest.raises(ValueError, match=match):
        camera_from_opencv(args["K"], args["R"], args["t"], 64, 48)
    with pytest.raises(ValueError, match="c2w must have shape"):
        camera_from_c2w(np.eye(3), K, 64, 48)


def test_a_rotation_fit_converges_from_60_degrees_at_the_euler_lock():
    # The target looks straight down (where the Euler angles lock, above); Adam on the
    # camera's quaternion finds it from 60 degrees away, turned about the camera's up axis
    # (the turn yaw and roll cannot make there) and about a random one.  The image loss is
    # rasterized colours of an environment coloured by direction.
    from experiments.camera_models import (
        fit_rotation,
        pose_problem,
        rotation_angle,
        start_axes,
        turned,
    )

    loss_and_grad, target = pose_problem(32, 24)
    axes = start_axes(target, 5)
    for axis in (axes[0], axes[4]):
        start = turned(target, axis, 60.0)
        assert rotation_angle(start, target) == pytest.approx(60.0, abs=1e-6)
        q = fit_rotation(loss_and_grad, start, euler=False, steps=150, lr=0.05)
        assert rotation_angle(q, target) < 0.5, axis
