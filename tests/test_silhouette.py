"""Analytic antialiasing: topology, identity off silhouettes, gradients vs finite differences.

Two kinds of gradient check: per pixel, with steps too small to cross a pixel centre (the blend's
own derivative), and of the image's sums (area, centroid) over steps of one pixel, which cross
pixel centres where the z-buffer's coverage flips, held against closed forms and a supersampled
render (the image must be continuous there for the two to agree).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from jaxgfx._src.outline_walk import near_silhouettes
from jaxgfx._src.silhouette import _walk_frame
from jaxgfx.camera import (
    camera_basis,
    camera_from_degrees,
    look_at,
    project,
    screen_to_camera,
    supersampled,
    yaw_pitch_roll_rotation,
)
from jaxgfx.raster import rasterize
from jaxgfx.silhouette import analytic_antialias, silhouette_edges

# Per pixel: analytic d(image)/d(vertex) matches central finite differences in sign and within
# 10 % in magnitude on >= 95 % of the edge pixels whose derivative is above float32 rounding.
GRAD_RTOL = 0.10
GRAD_AGREE = 0.95
# Central-difference step in world units: the silhouette moves ~0.005 px, so few pixel
# centres are crossed, yet the float32 image changes by ~1e-3, far above rounding.
FD_STEP = 1e-4
# The camera moves every edge at once, and fast (yaw: ~40 px per radian), so a smaller step
# keeps more edge pixels away from the kinks where an edge crosses a pixel centre.
CAM_FD_STEP = 1e-5
# Antialiased silhouette pixels are at least this much closer (mean |error|) to an 8x8
# supersampled render than the z-buffer's (measured: 0.008 against 0.061).
AA_GAIN = 0.25

# Every scene is padded to these sizes and every camera is 48x32, so the jitted render, jvp
# and gradient below compile once for the whole file.
NV, NF = 36, 12
W, H = 48, 32


def _pad(v, f, c, edges=None):
    """Pads a mesh to NV vertices (unused copies) and NF faces (zero-area [0, 0, 0])."""
    v, f, c = (np.asarray(a) for a in (v, f, c))
    v = np.concatenate([v, np.repeat(v[:1], NV - len(v), 0)]).astype(np.float32)
    c = np.concatenate([c, np.repeat(c[:1], NV - len(c), 0)]).astype(np.float32)
    f = np.concatenate([f, np.zeros((NF - len(f), 3), int)]).astype(np.int32)
    if edges is None:
        return v, f, c, silhouette_edges(f)
    e = np.concatenate([edges, -np.ones((NF - len(edges), 3), int)]).astype(np.int32)
    return v, f, c, e


CUBE = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
# Distinct per-vertex colours, so that interior edges are visible steps too.
CUBE_V, CUBE_F, CUBE_C, CUBE_E = _pad(
    CUBE.vertices, CUBE.faces, (CUBE.vertices + 0.5) * np.array([0.8, 0.6, 0.9]) + 0.1
)
CUBE_CAM = look_at([1.4, 1.1, -2.3], [0.0, 0.0, 0.0], fov=45.0, width=W, height=H)


@jax.jit
def _render(cam, v, f, c, e):
    out = rasterize(cam, v, f, c)
    return analytic_antialias(cam, v, f, out, edges=e), out


def _cube_aa(cam, v):
    aa, out = _render(cam, v, CUBE_F, CUBE_C, CUBE_E)
    return aa, out.color, out.tri_id


@jax.jit
def _cube_jvp(cam, v, dcam, dv):
    """Forward-mode derivative of the antialiased cube image along (dcam, dv)."""
    return jax.jvp(lambda c, x: _cube_aa(c, x)[0], (cam, v), (dcam, dv))[1]


@jax.jit
def _grad_sq(cam, v, f, c, e):
    """Gradient of sum(image**2) w.r.t. the vertices and the camera."""
    return jax.grad(lambda x, k: jnp.sum(_render(k, x, f, c, e)[0] ** 2), argnums=(0, 1))(v, cam)


def _no_move(cam):
    return jax.tree_util.tree_map(jnp.zeros_like, cam)


def _reference_across(faces):
    """Brute force: for each face edge, the same edge in the one other face holding it."""
    out = np.full(faces.shape, -1)
    for f, e in itertools.product(range(len(faces)), range(3)):
        ends = {faces[f, e], faces[f, (e + 1) % 3]}
        others = [
            3 * g + k
            for g, k in itertools.product(range(len(faces)), range(3))
            if g != f and {faces[g, k], faces[g, (k + 1) % 3]} == ends
        ]
        if len(others) == 1:
            out[f, e] = others[0]
    return out


def test_silhouette_edges_match_brute_force():
    # A closed cube: every edge manifold; a fan with a non-manifold fin and boundary edges.
    fan = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [2, 1, 4], [1, 2, 5]], np.int32)
    for faces in (np.asarray(CUBE.faces), fan):
        np.testing.assert_array_equal(silhouette_edges(faces), _reference_across(faces))
    assert (CUBE_E[:12] >= 0).all() and (CUBE_E[12:] == -1).all()
    np.testing.assert_array_equal(silhouette_edges(np.array([[0, 1, 2]])), -np.ones((1, 3)))
    with pytest.raises(ValueError, match="faces"):
        silhouette_edges(np.zeros((4, 2), np.int32))
    with pytest.raises(TypeError, match="faces"):
        silhouette_edges(np.zeros((4, 3), np.float32))
    with pytest.raises(ValueError, match="vertices"):
        silhouette_edges(np.asarray(CUBE.faces), np.zeros((8, 2)))
    with pytest.raises(ValueError, match="index"):
        silhouette_edges(np.asarray(CUBE.faces), np.zeros((5, 3)))


def _split(vertices, faces):
    """Three vertices of its own per face (as flat-shaded glTF meshes store them)."""
    f = np.asarray(faces)
    return np.asarray(vertices)[f].reshape(-1, 3), np.arange(f.size).reshape(-1, 3)


def test_split_vertices_are_welded_by_position():
    v, f = _split(CUBE.vertices, CUBE.faces)
    c = np.asarray(CUBE_C)[np.asarray(CUBE.faces)].reshape(-1, 3)
    welded = silhouette_edges(f, v)
    # The same faces across as the shared-vertex cube, edge for edge.
    np.testing.assert_array_equal(welded, silhouette_edges(np.asarray(CUBE.faces)))
    assert (silhouette_edges(f) == -1).all()  # unwelded, every edge is a boundary
    sv, sf, sc, _ = _pad(v, f, c)
    split_aa, _ = _render(CUBE_CAM, sv, sf, sc, _pad(v, f, c, welded)[3])
    np.testing.assert_allclose(split_aa, _cube_aa(CUBE_CAM, CUBE_V)[0], atol=1e-5)
    # Unwelded, the interior edges of a cube face blend as outlines.
    loose_aa, _ = _render(CUBE_CAM, sv, sf, sc, _pad(v, f, c, silhouette_edges(f))[3])
    assert np.abs(np.asarray(loose_aa) - np.asarray(split_aa)).max() > 0.05


def test_full_screen_quad_is_unchanged():
    # Two triangles covering the whole frame: their shared diagonal is not a silhouette.
    cam = camera_from_degrees([0.0, 0.0, -2.0], fov=40.0, width=W, height=H)
    v, f, c, e = _pad(
        [[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]],
        [[0, 1, 2], [0, 2, 3]],
        [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]],
    )
    aa, out = _render(cam, v, f, c, e)
    assert len(np.unique(out.tri_id)) == 2 and (out.tri_id >= 0).all()
    np.testing.assert_array_equal(aa, out.color)


def test_only_silhouettes_blend():
    aa, color, tri = (np.asarray(a) for a in _cube_aa(CUBE_CAM, CUBE_V))
    changed = np.abs(aa - color).max(-1) > 0
    bg = tri < 0
    near_bg = bg.copy()
    near_bg[:, 1:] |= bg[:, :-1]
    near_bg[:, :-1] |= bg[:, 1:]
    near_bg[1:] |= bg[:-1]
    near_bg[:-1] |= bg[1:]
    # Three faces meet in the view with visible colour steps between them, yet only pixels
    # next to the background change: interior edges of the convex cube are never silhouettes.
    assert len(np.unique(tri[~bg])) >= 3
    assert changed.sum() > 20 and not (changed & ~near_bg).any()
    assert np.abs(aa - color).max() <= 1.0 + 1e-6


def test_closer_to_supersampling_than_the_raw_image():
    # Independent reference: the 8x8-supersampled render averaged down (exact coverage up to
    # 1/64).  On pixels next to the background the blend must remove most of the aliasing.
    aa, color, tri = (np.asarray(a) for a in _cube_aa(CUBE_CAM, CUBE_V))
    big = supersampled(CUBE_CAM, (8, 8))
    fine = jax.jit(lambda cam: rasterize(cam, CUBE_V, CUBE_F, CUBE_C).color)(big)
    ref = np.asarray(fine).reshape(H, 8, W, 8, 3).mean((1, 3))
    bg = tri < 0
    sil = np.zeros(bg.shape, bool)  # both pixels of every pair across the outline
    for d, a, b in (
        (bg[:, 1:] != bg[:, :-1], np.s_[:, 1:], np.s_[:, :-1]),
        (bg[1:] != bg[:-1], np.s_[1:], np.s_[:-1]),
    ):
        sil[a] |= d
        sil[b] |= d
    raw_err = np.abs(color - ref)[sil].mean()
    aa_err = np.abs(aa - ref)[sil].mean()
    assert sil.sum() > 50 and aa_err <= AA_GAIN * raw_err, (raw_err, aa_err)


def _fd_agreement(dcam, dv, step=FD_STEP):
    """Edge pixel channels, and the fraction where the jvp matches central differences."""
    v = jnp.asarray(CUBE_V)

    def image(step):
        cam = jax.tree_util.tree_map(lambda a, d: a + step * d, CUBE_CAM, dcam)
        return np.asarray(_cube_aa(cam, v + step * dv)[0])

    fd = (image(step) - image(-step)) / (2 * step)
    an = np.asarray(_cube_jvp(CUBE_CAM, v, dcam, dv))
    tri = np.asarray(_cube_aa(CUBE_CAM, v)[2])
    edge = np.zeros(tri.shape, bool)
    edge[:, 1:] |= tri[:, 1:] != tri[:, :-1]
    edge[:, :-1] |= tri[:, 1:] != tri[:, :-1]
    edge[1:] |= tri[1:] != tri[:-1]
    edge[:-1] |= tri[1:] != tri[:-1]
    # Edge pixel channels where either derivative is above 1e-3 of the largest and above the
    # finite difference's float32 rounding (a few ulps of pixel values near 1, over 2 steps).
    noise = 16 * np.finfo(np.float32).eps / (2 * step)
    sig = (np.abs(fd) + np.abs(an) > max(1e-3 * np.abs(an).max(), noise)) & edge[..., None]
    ok = (np.sign(fd) == np.sign(an)) & (np.abs(an - fd) <= GRAD_RTOL * np.abs(fd))
    return int(sig.sum()), float(ok[sig].mean())


@pytest.mark.parametrize("vertex", ["rightmost", "topmost"])
def test_vertex_gradients_match_finite_differences(vertex):
    sx = np.asarray(project(CUBE_CAM, CUBE_V)[0])
    k = int(np.argmax(sx[:, 0]) if vertex == "rightmost" else np.argmin(sx[:, 1]))
    for axis in range(3):
        dv = jnp.zeros(CUBE_V.shape).at[k, axis].set(1.0)
        n, frac = _fd_agreement(_no_move(CUBE_CAM), dv)
        assert n >= 6 and frac >= GRAD_AGREE, (vertex, axis, n, frac)


def _camera_tangents(field):
    """Camera tangents along one kind of motion: a turn (yaw or pitch) or a field's axes."""
    still = _no_move(CUBE_CAM)
    if field in ("yaw", "pitch"):
        angles = tuple(jnp.float32(a) for a in (CUBE_CAM.yaw, CUBE_CAM.pitch, CUBE_CAM.roll))
        turn = tuple(jnp.float32(name == field) for name in ("yaw", "pitch", "roll"))
        _, dq = jax.jvp(yaw_pitch_roll_rotation, angles, turn)
        return [dataclasses.replace(still, rotation=dq)]
    # Pixels move by 1e3 x the step (1 / 100 px) along focal lengths and principal point.
    scale = 1.0 if field == "position" else 1e3
    axes = np.eye(3 if field == "position" else 2, dtype=np.float32) * scale
    return [dataclasses.replace(still, **{field: jnp.asarray(d)}) for d in axes]


@pytest.mark.parametrize("field", ["yaw", "pitch", "position", "focal", "principal"])
def test_camera_gradients_match_finite_differences(field):
    # A turn moves the quaternion's components (about 0.5) by the step: 4x the step keeps
    # the float32 quaternion's rounding (6e-8) out of the central difference.
    step = 4 * CAM_FD_STEP if field in ("yaw", "pitch") else CAM_FD_STEP
    for dcam in _camera_tangents(field):
        n, frac = _fd_agreement(dcam, jnp.zeros(CUBE_V.shape), step)
        assert n >= 20 and frac >= GRAD_AGREE, (field, n, frac)


def test_jacobian_on_a_triangle_matches_central_differences():
    cam = camera_from_degrees([0.0, 0.0, -3.0], fov=40.0, width=W, height=H)
    # Corners placed on screen so that no pixel centre is within 0.15 px of an edge line:
    # steps of ~0.02 px then never flip a pixel, and the visibility (tri_id, depth) may be
    # held fixed; the derivative is the one the full pipeline sees (the finite-difference
    # tests check that end to end).
    screen = np.array([[10.25, 8.3], [30.25, 8.3], [10.25, 28.3]])
    depth = np.array([3.0, 3.2, 2.9])
    xr, yr = (np.asarray(a) for a in screen_to_camera(cam, screen[:, 0], screen[:, 1]))
    right, up, fwd = (np.asarray(a) for a in camera_basis(cam))
    corners = np.asarray(cam.position) + depth[:, None] * (
        xr[:, None] * right + yr[:, None] * up + fwd
    )
    v, f, c, e = _pad(corners, [[0, 1, 2]], [[1.0, 0.2, 0.0], [0.0, 1.0, 0.3], [0.2, 0.0, 1.0]])
    p = np.asarray(project(cam, v[:3])[0])
    gx, gy = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    for a, b in ((p[0], p[1]), (p[1], p[2]), (p[2], p[0])):
        d = b - a
        assert (np.abs(d[0] * (gy - a[1]) - d[1] * (gx - a[0])) / np.hypot(*d)).min() > 0.15
    _, out = _render(cam, v, f, c, e)
    weights = jax.random.uniform(jax.random.PRNGKey(0), (H, W, 3))

    @jax.jit
    def loss(x):
        # Only the blend terms: away from edges they are exact zeros, so no rounding noise.
        return jnp.sum(
            weights * (analytic_antialias(cam, x, f, out, out.color, edges=e) - out.color)
        )

    # Reverse mode, per coordinate of the three corners, against central differences of the
    # float32 loss (steps of 1e-3 move an edge by ~0.015 px).
    grad = np.asarray(jax.jit(jax.grad(loss))(jnp.asarray(v)))
    assert np.abs(grad[:3, :2]).max() > 10.0 and not grad[3:].any()
    for k, axis in itertools.product(range(3), range(3)):
        dv = np.zeros_like(v)
        dv[k, axis] = 1e-3
        fd = (float(loss(v + dv)) - float(loss(v - dv))) / 2e-3
        assert abs(grad[k, axis] - fd) <= 0.01 * abs(fd) + 0.05, (k, axis, grad[k, axis], fd)


def test_degenerate_input_gives_finite_values_and_gradients():
    cam = camera_from_degrees([0.0, 0.0, -3.0], fov=50.0, width=W, height=H, near=0.1)
    v, f, c, e = _pad(
        [
            [-0.8, -0.6, 0.0], [0.2, -0.5, 0.0], [-0.3, 0.4, 0.0],  # an ordinary triangle
            [0.3, -0.8, 0.0], [0.35, -0.2, 0.5], [0.21, -0.5, -0.9],  # edge-on: x = (z + 3) / 10
            [0.5, 0.3, 0.0], [0.9, 0.6, 0.0],  # a zero-area face (repeated vertex)
            [-1.0, 0.8, -3.5], [0.8, 0.9, 1.0], [-0.4, 0.2, 0.5],  # one vertex behind the eye
        ],
        [[0, 1, 2], [3, 4, 5], [6, 7, 7], [8, 9, 10]],
        np.linspace(0.1, 1.0, 33).reshape(11, 3),
    )  # fmt: skip
    aa, out = _render(cam, v, f, c, e)
    tri = np.asarray(out.tri_id)
    assert np.isfinite(np.asarray(aa)).all() and (tri == 0).any() and (tri == 3).any()
    assert np.abs(np.asarray(aa) - np.asarray(out.color)).max() > 0.1
    gv, gc = _grad_sq(cam, v, f, c, e)
    for leaf in (gv, *jax.tree_util.tree_leaves(gc)):
        assert np.isfinite(np.asarray(leaf)).all()
    assert np.abs(np.asarray(gv)).max() > 0


def test_bad_input_is_rejected():
    _, out = _render(CUBE_CAM, CUBE_V, CUBE_F, CUBE_C, CUBE_E)
    with pytest.raises(ValueError, match="color"):
        analytic_antialias(CUBE_CAM, CUBE_V, CUBE_F, out, np.zeros((H, W - 1, 3)))
    with pytest.raises(ValueError, match="edges"):
        analytic_antialias(CUBE_CAM, CUBE_V, CUBE_F, out, edges=CUBE_E[:-1])
    small = dataclasses.replace(CUBE_CAM, width=W // 2)
    with pytest.raises(ValueError, match="tri_id"):
        analytic_antialias(small, CUBE_V, CUBE_F, out, out.color[:, : W // 2])
    with pytest.raises(TypeError, match="concrete"):
        jax.jit(lambda f: analytic_antialias(CUBE_CAM, CUBE_V, f, out))(CUBE_F)


def test_vmap_over_cameras_equals_loop():
    cams = [CUBE_CAM, look_at([-1.5, 0.8, -2.2], [0.0, 0.0, 0.0], fov=45.0, width=W, height=H)]
    outs = [_render(c, CUBE_V, CUBE_F, CUBE_C, CUBE_E) for c in cams]
    stack = lambda *xs: jnp.stack(xs)  # noqa: E731
    aa_batch = jax.jit(
        jax.vmap(lambda c, o: analytic_antialias(c, CUBE_V, CUBE_F, o, edges=CUBE_E))
    )
    batched = aa_batch(
        jax.tree_util.tree_map(stack, *cams), jax.tree_util.tree_map(stack, *(o for _, o in outs))
    )
    for i, (aa, _) in enumerate(outs):
        # A differently fused float32 program: the crossing (a ratio of dot products of
        # camera-space cross products) carries ~1e-5 of rounding.
        np.testing.assert_allclose(batched[i], aa, atol=1e-4)


# --- The image's sums over steps that cross pixel centres -------------------------------------
# An icosphere of radius 0.8 (3 subdivisions), 3 units from a 96x72 camera (60 degree field of
# view): about 930 px^2, whose outline crosses a few pixel centres per 0.05 % of scale.  The
# ellipsoid has the sphere's faces (one compile serves both) and an outline of every slope.
SW, SH = 96, 72
SPHERE = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
SPHERE_F = np.asarray(SPHERE.faces, np.int32)
SPHERE_E = silhouette_edges(SPHERE_F)
SPHERE_V = np.asarray(SPHERE.vertices, np.float32)
SPHERE_CAM = look_at([0.0, 0.0, -3.0], [0.0, 0.0, 0.0], 60.0, SW, SH)
_TURN = trimesh.transformations.rotation_matrix(0.7, [0.3, 0.5, 0.8])[:3, :3]
ELLIPSOID_V = ((SPHERE_V * [1.0, 0.55, 0.75]) @ _TURN.T + [0.15, -0.1, 0.0]).astype(np.float32)
# Motion parameters: translation (3), rotation vector (3) about the origin, log scale, yaw.
MOTIONS = ("translate x", "translate y", "translate z", "rotate x", "rotate y", "rotate z")
MOTIONS += ("scale", "camera yaw")
NP = len(MOTIONS)
SS = 8  # supersampling per axis of the independent reference


def _moved(p, verts):
    w = p[3:6]
    k = jnp.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    rot = jax.scipy.linalg.expm(k)
    turned = yaw_pitch_roll_rotation(SPHERE_CAM.yaw + p[7], SPHERE_CAM.pitch, SPHERE_CAM.roll)
    cam = dataclasses.replace(SPHERE_CAM, rotation=turned)
    return cam, jnp.exp(p[6]) * verts @ rot.T + p[:3]


def _sums(img):
    ys, xs = np.mgrid[0:SH, 0:SW] + 0.5
    area = jnp.sum(img)
    return jnp.stack([area, jnp.sum(img * xs) / area, jnp.sum(img * ys) / area])


def _coverage_sums(p, verts):
    cam, v = _moved(p, verts)
    out = rasterize(cam, v, SPHERE_F, jnp.ones((v.shape[0], 1)))
    cov = (out.tri_id >= 0).astype(jnp.float32)[..., None]
    img = analytic_antialias(cam, v, SPHERE_F, out, cov, edges=SPHERE_E, background=0.0)
    return _sums(img[..., 0])


_cov_sums = jax.jit(_coverage_sums)
_cov_jac = jax.jit(jax.jacrev(_coverage_sums))


@jax.jit
def _ss_sums(p, verts):
    cam, v = _moved(p, verts)
    big = supersampled(cam, (SS, SS))
    cov = (rasterize(big, v, SPHERE_F, jnp.ones((v.shape[0], 1))).tri_id >= 0).astype(jnp.float32)
    return _sums(cov.reshape(SH, SS, SW, SS).mean((1, 3)))


def _hull_area(s):
    """Exact projected area of the scaled sphere mesh (convex: the hull of its vertices)."""
    f = 0.5 * SH / np.tan(np.radians(30.0))
    v = SPHERE.vertices * s
    z = v[:, 2] + 3.0
    return ConvexHull(np.stack([f * v[:, 0] / z, f * v[:, 1] / z], 1)).volume


def _unit(k):
    u = np.zeros(NP, np.float32)
    u[k] = 1.0
    return u


def test_sphere_area_is_continuous_across_pixel_centres():
    # The z-buffer's area is a staircase in the scale (steps of 0 to 8 px^2 as pixel centres
    # are crossed); the antialiased area must rise with the exact area at every step (measured:
    # within 0.16 px^2 of steps of about 1 px^2).
    scales = np.linspace(0.99, 1.01, 41)
    areas = np.array([float(_cov_sums(np.log(s) * _unit(6), SPHERE_V)[0]) for s in scales])
    steps = np.diff(areas)
    exact = np.diff([_hull_area(s) for s in scales])
    assert np.abs(steps - exact).max() < 0.5, steps - exact


def test_sphere_area_and_its_derivative_match_the_closed_form():
    zero = np.zeros(NP, np.float32)
    area = float(_cov_sums(zero, SPHERE_V)[0])
    ad = float(np.asarray(_cov_jac(zero, SPHERE_V))[0] @ _unit(6))  # d/d(log s) = d/ds at 1
    fd = (
        float(_cov_sums(np.log(1.02) * _unit(6), SPHERE_V)[0])
        - float(_cov_sums(np.log(0.98) * _unit(6), SPHERE_V)[0])
    ) / 0.04
    exact = (_hull_area(1.02) - _hull_area(0.98)) / 0.04
    ss_area = float(_ss_sums(zero, SPHERE_V)[0])
    assert abs(area - _hull_area(1.0)) < 0.002 * area
    assert abs(area - ss_area) < 0.01 * area
    assert abs(ad - exact) < 0.01 * exact and abs(fd - exact) < 0.01 * exact, (ad, fd, exact)


# Sums over a 1-px step, against both references (measured: area within 0.6 px^2, 1-4 %;
# centroids within 0.012 px); a gradient 7 times too small misses the area by 85 %.
AREA_TOL = (0.02, 0.3)  # relative, px^2
CENTROID_TOL = (0.02, 0.02)  # relative, px


@pytest.mark.parametrize(
    "motion", ["translate x", "translate z", "rotate x", "rotate y", "scale", "camera yaw"]
)
def test_sums_follow_one_pixel_steps_and_the_supersampled_reference(motion):
    u = _unit(MOTIONS.index(motion))
    zero = np.zeros(NP, np.float32)
    # The step that moves the ellipsoid's fastest vertex by one pixel.
    speed = jax.jvp(lambda p: project(*_moved(p, ELLIPSOID_V))[0], (zero,), (u,))[1]
    h = 1.0 / float(np.linalg.norm(np.asarray(speed), axis=-1).max())
    ad = np.asarray(_cov_jac(zero, ELLIPSOID_V)) @ u * h
    fd = np.asarray(_cov_sums(h * u, ELLIPSOID_V)) - np.asarray(_cov_sums(-h * u, ELLIPSOID_V))
    ss = np.asarray(_ss_sums(h * u, ELLIPSOID_V)) - np.asarray(_ss_sums(-h * u, ELLIPSOID_V))
    for ref in (fd / 2, ss / 2):
        for k, (rel, tol) in enumerate((AREA_TOL, CENTROID_TOL, CENTROID_TOL)):
            assert abs(ad[k] - ref[k]) <= rel * abs(ref[k]) + tol, (motion, k, ad, fd / 2, ss / 2)


def _screen_quads(cam, quads, depths):
    """Planar quads given by screen rectangles (x0, x1, y0, y1) at camera depths, padded."""
    right, up, fwd = (np.asarray(a) for a in camera_basis(cam))
    verts, faces = [], []
    for (x0, x1, y0, y1), z in zip(quads, depths, strict=True):
        xs, ys = np.array([x0, x1, x1, x0]), np.array([y0, y0, y1, y1])
        xr, yr = (np.asarray(a) for a in screen_to_camera(cam, xs, ys))
        base = len(verts)
        verts += list(np.asarray(cam.position) + z * (xr[:, None] * right + yr[:, None] * up + fwd))
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return _pad(np.asarray(verts), np.asarray(faces), np.ones((len(verts), 3)))


def test_the_outline_is_found_across_faces_thinner_than_a_pixel():
    # A rectangle ending at x = 20.3 whose last 0.3 px is a separate strip of two faces: the
    # pixel centre at x = 19.5 sees the wide part, which does not hold the outline; x = 20.5 is
    # empty.  In a row the column-20 pixel is 0.3 covered, column 19 fully.
    cam = camera_from_degrees([0.0, 0.0, -3.0], fov=40.0, width=W, height=H)
    v, f, c, _ = _screen_quads(cam, [(5.0, 20.0, 4.2, 26.7), (20.0, 20.3, 4.2, 26.7)], [3, 3])
    aa, out = _render(cam, v, f, c, silhouette_edges(f, v))
    tri = np.asarray(out.tri_id)
    assert (tri[6:24, 19] == 0).all() or (tri[6:24, 19] == 1).all()
    assert (tri[6:24, 20] == -1).all()
    np.testing.assert_allclose(np.asarray(aa)[6:24, 19:21, 0], [[1.0, 0.3]] * 18, atol=1e-4)


_render_gap = jax.jit(
    lambda cam, v, f, c, e: analytic_antialias(
        cam, v, f, rasterize(cam, v, f, c), edges=e, background=0.0
    )
)


def test_a_gap_narrower_than_a_pixel_shows_the_background():
    # Two rectangles with a 0.5 px gap between x = 19.8 and 20.3, the right one farther: both
    # pixel centres of the pair (19.5 and 20.5) are covered, so only the background colour can
    # say that half a pixel is empty.  Box coverage per row: 0.8 and 0.7.
    cam = camera_from_degrees([0.0, 0.0, -3.0], fov=40.0, width=W, height=H)
    v, f, c, e = _screen_quads(cam, [(5.0, 19.8, 4.2, 26.7), (20.3, 40.0, 4.2, 26.7)], [3, 3.5])
    with_bg = np.asarray(_render_gap(cam, v, f, c, e))[6:24, 19:21, 0]
    np.testing.assert_allclose(with_bg, [[0.8, 0.7]] * 18, atol=1e-4)
    # Without a background colour, the front outline blends towards the other pixel's colour.
    without, _ = _render(cam, v, f, c, e)
    np.testing.assert_allclose(np.asarray(without)[6:24, 19:21, 0], 1.0, atol=1e-6)


# --- Which pairs walk: the culling near silhouette edges -------------------------------------
# A torus seen obliquely: its inner rim hides part of the far side, so outlines run inside the
# covered area as well as around it, and its faces are about a pixel wide.  SW x SH, as the
# sphere's frames.
TORUS = trimesh.creation.torus(
    major_radius=0.6, minor_radius=0.25, major_sections=48, minor_sections=24
)
TORUS_V = np.asarray(TORUS.vertices, np.float32)
TORUS_F = np.asarray(TORUS.faces, np.int32)
TORUS_CAM = look_at([0.0, 0.8, -1.6], [0.0, 0.0, 0.0], 50.0, SW, SH)


@functools.partial(jax.jit, static_argnames="cull")
def _crossed_edges(cam, v, f, e, cull):
    """Per pair slot, the face and edge (3 face + edge) whose outline its walk crossed, or -1,
    and how many pairs were walked."""
    out = rasterize(cam, v, f)
    found, _ = _walk_frame(cam, v, f, e, out.tri_id, out.depth, background=True, cull=cull)
    q = found.pairs.shape[0]
    crossed = jnp.where(found.face >= 0, 3 * found.face + found.edge, -1)
    per_pair = jnp.full((2, q), -1, jnp.int32).at[:, found.pairs].set(crossed, mode="drop")
    walked = jnp.sum(found.pairs < q)
    return per_pair, walked


def test_culled_pairs_cross_no_outline():
    edges = silhouette_edges(TORUS_F)
    culled, walked = _crossed_edges(TORUS_CAM, TORUS_V, TORUS_F, edges, cull=True)
    every, all_walked = _crossed_edges(TORUS_CAM, TORUS_V, TORUS_F, edges, cull=False)
    # The culling leaves pairs out (half of them here; else this checks nothing), and every
    # walk from the front pixel and back from the other finds the same edge as without it.
    assert int(walked) < 0.7 * int(all_walked)
    assert (np.asarray(every)[0] >= 0).sum() > 300
    np.testing.assert_array_equal(np.asarray(culled), np.asarray(every))


@functools.partial(jax.jit, static_argnames="shape")
def _near(onward, faces, screen, z, shape):
    return near_silhouettes(onward, faces, screen, z, shape)


def test_near_silhouettes_marks_the_reach_of_each_silhouette_face():
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    screen = np.array([[10.0, 10.0], [12.0, 10.0], [12.0, 11.0], [200.0, 5.0]], np.float32)
    z = np.ones(4, np.float32)
    # Face 0 holds a silhouette edge, face 1 none: only face 0's box (grown by the reach, in
    # 4-pixel tiles) is marked.
    onward = np.array([[-1, 1, 1], [0, 0, 0]], np.int32)
    near = np.asarray(_near(onward, faces, screen, z, (24, 32)))
    assert near[10, 10] and near[10, 12] and near[11, 8]
    assert not near[20, 20] and not near[5, 30] and near.mean() < 0.2
    # A corner just in front of the eye projects far off screen (beyond int32): the box still
    # reaches the frame's edge.
    far = screen.copy()
    far[1] = [1e12, 10.0]
    reach = np.asarray(_near(onward, faces, far, z, (24, 32)))
    assert reach[10, 31] and reach[11, 20] and not reach[20, 20]
    # A silhouette face with a corner behind the eye plane has no bounded projection.
    behind = z.copy()
    behind[2] = -0.5
    assert np.asarray(_near(onward, faces, screen, behind, (24, 32))).all()
    # No silhouette edge, no walks.
    assert not np.asarray(_near(np.zeros_like(onward), faces, screen, z, (24, 32))).any()
