"""Rasterizer vs trimesh ray casting, fill rule, clipping, culling, batching, bad input."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxgfx.camera import (
    camera_basis,
    camera_from_degrees,
    camera_from_opencv,
    look_at,
    orbit_cameras,
    pixel_rays,
    supersampled,
    yaw_pitch_roll_rotation,
)
from jaxgfx.io import load_mesh, mesh_arrays
from jaxgfx.raster import coverage_count, rasterize

# Acceptance tolerance: depth within 1e-3 of the depth range on >= 99.5 % of pixels.
DEPTH_TOL = 1e-3
AGREE = 0.995


def trimesh_depth(mesh: trimesh.Trimesh, cam) -> np.ndarray:
    """Independent reference: first hit beyond the near plane of each pixel ray (trimesh)."""
    o, d = (np.asarray(a, np.float64).reshape(-1, 3) for a in pixel_rays(cam, normalize=True))
    fwd = np.asarray(camera_basis(cam)[2], np.float64)
    loc, ray_idx, _ = mesh.ray.intersects_location(o, d, multiple_hits=True)
    depth = np.full(len(o), np.inf)
    z = (loc - o[ray_idx]) @ fwd
    keep = z >= float(cam.near)
    np.minimum.at(depth, ray_idx[keep], z[keep])
    return depth.reshape(cam.height, cam.width)


def agreement(ours: np.ndarray, ref: np.ndarray) -> float:
    fin = np.isfinite(ref)
    rng = ref[fin].max() - ref[fin].min() if fin.any() else 1.0
    both = np.isfinite(ours) & fin
    diff = np.abs(np.where(both, ours, 0.0) - np.where(both, ref, 0.0))
    ok = (~np.isfinite(ours) & ~fin) | (both & (diff <= DEPTH_TOL * rng))
    return float(ok.mean())


def _cams_for(mesh, w=64, h=48):
    lo, hi = mesh.bounds
    c = 0.5 * (lo + hi)
    r = 0.5 * float(np.linalg.norm(hi - lo))
    cams = [
        look_at(c + r * np.array([0.3, 0.5, 2.5]), c, 45, w, h, 0.01 * r, 100 * r),
        look_at(c + r * np.array([-2.0, -0.6, -1.2]), c, 45, w, h, 0.01 * r, 100 * r),
        look_at(c + r * np.array([0.0, 3.0, 0.001]), c, 45, w, h, 0.01 * r, 100 * r),
    ]
    # The near plane cuts through the mesh: put it at the 15 % quantile of vertex depths.
    eye = c + r * np.array([0.0, 0.1, 1.3])
    probe = look_at(eye, c, 60, w, h, 0.01 * r, 100 * r)
    z = (np.asarray(mesh.vertices) - eye) @ np.asarray(camera_basis(probe)[2])
    cams.append(look_at(eye, c, 60, w, h, float(np.quantile(z, 0.15)), 100 * r))
    return cams


def _check_mesh(mesh, raster_jit, cams=None):
    v = np.asarray(mesh.vertices, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    cams = _cams_for(mesh) if cams is None else cams
    for k, cam in enumerate(cams):
        out = raster_jit(cam, v, f, v)
        ref = trimesh_depth(mesh, cam)
        ours = np.asarray(out.depth)
        a = agreement(ours, ref)
        assert a >= AGREE, f"camera {k}: depth agrees on {a:.4f} of pixels"
        assert np.isfinite(ref).any()
    # the near-plane camera really clips: some triangle has vertices on both sides
    zc = (v - np.asarray(cams[-1].position)) @ np.asarray(camera_basis(cams[-1])[2])
    tri_z = zc[f]
    near = float(cams[-1].near)
    assert np.any((tri_z.min(1) < near) & (tri_z.max(1) > near))


def test_depth_matches_trimesh_on_primitive(raster_jit):
    mesh = trimesh.creation.torus(1.0, 0.35, major_sections=24, minor_sections=12)
    _check_mesh(mesh, raster_jit)


def test_depth_matches_trimesh_with_half_width_pixels(raster_jit):
    # The thesis's 2x1 AA frame: same view, pixels half as wide (pixel_aspect 0.5).
    mesh = trimesh.creation.torus(1.0, 0.35, major_sections=24, minor_sections=12)
    cams = [supersampled(c, (2, 1)) for c in _cams_for(mesh, w=32, h=48)]
    assert float(cams[0].pixel_aspect) == 0.5 and cams[0].shape == (48, 64)
    _check_mesh(mesh, raster_jit, cams)


def test_depth_matches_trimesh_on_bunny(raster_jit, data_dir):
    mesh = load_mesh(data_dir / "meshes" / "bun_zipper_res2.ply")
    _check_mesh(mesh, raster_jit)


def test_an_opencv_camera_sees_what_its_rays_meet(raster_jit):
    # A COLMAP-like camera (fx != fy, principal point 9 % and 6 % off centre, rolled): the
    # depth is that of its pixels' rays written from K, R and t alone, met by trimesh.
    from experiments.camera_models import (
        opencv_intrinsics,
        opencv_look_at,
        opencv_pixel_rays,
        trimesh_depth,
    )

    mesh = trimesh.creation.torus(1.0, 0.35, major_sections=24, minor_sections=12)
    v, f = np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int32)
    K = opencv_intrinsics(64, 48)
    R, t = opencv_look_at([0.9, 2.2, -2.4], [0.3, 0.0, 0.2], roll=-17.0)
    cam = camera_from_opencv(K, R, t, 64, 48, near=0.01, far=100.0)
    ref = trimesh_depth(v, f, *opencv_pixel_rays(K, R, t, 64, 48))
    assert 0.2 < np.isfinite(ref).mean() < 0.9
    a = agreement(np.asarray(raster_jit(cam, v, f, v).depth), ref)
    assert a >= AGREE, a


def _screen_grid(cam, n=9, jitter=0.2, seed=0, depth=2.0):
    """A planar, gap-free tessellation covering the whole view at ``depth``."""
    rng = np.random.default_rng(seed)
    half = 3.0
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n))
    x[1:-1, 1:-1] += rng.uniform(-jitter, jitter, (n - 2, n - 2))
    y[1:-1, 1:-1] += rng.uniform(-jitter, jitter, (n - 2, n - 2))
    v = np.stack([x, y, np.full_like(x, depth)], -1).reshape(-1, 3).astype(np.float32)
    i = np.arange(n - 1)
    ii, jj = np.meshgrid(i, i)
    a = (jj * n + ii).ravel()
    b, c = a + 1, a + n
    d = c + 1
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]).astype(np.int32)
    return v, f


def test_fill_rule_each_pixel_exactly_once():
    count = jax.jit(coverage_count)  # one compile per mesh size, not one per call
    cam = camera_from_degrees([0, 0, 0], 0, 0, 0, 60, 37, 29)
    for seed in range(3):
        v, f = _screen_grid(cam, seed=seed)
        cc = np.asarray(count(cam, v, f))
        assert cc.min() == 1 and cc.max() == 1
    # vertices and edges exactly on pixel centres: ties must go to one triangle
    cam = camera_from_degrees([0, 0, 0], 0, 0, 0, 90, 16, 16)
    xs = np.array([-8.0, -4.5, -0.5, 3.5, 8.0])  # at z = 8 pixel centre k+0.5 <-> x = k+0.5-8
    x, y = np.meshgrid(xs, xs)
    v = np.stack([x, y, np.full_like(x, 8.0)], -1).reshape(-1, 3).astype(np.float32)
    i = np.arange(4)
    ii, jj = np.meshgrid(i, i)
    a = (jj * 5 + ii).ravel()
    b, c = a + 1, a + 5
    d = c + 1
    for f in (
        np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]),
        np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]),
    ):
        cc = np.asarray(count(cam, v, f.astype(np.int32)))
        assert cc.min() == 1 and cc.max() == 1


def test_near_plane_clipping_no_holes_no_smear(raster_jit):
    # A ground quad passing under and behind the camera: every triangle crosses the near plane.
    cam = camera_from_degrees([0, 1, 0], 0, -30, 0, 70, 40, 30, 0.5, 100.0)
    v = np.array([[-50, 0, -50], [50, 0, -50], [50, 0, 50], [-50, 0, 50]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2]], np.int32)
    out = raster_jit(cam, v, f, v)
    o, d = pixel_rays(cam, normalize=False)
    t = -np.asarray(o)[..., 1] / np.asarray(d)[..., 1]  # ray/plane y=0, t = depth
    expect = np.where((t >= 0.5) & (t <= 100.0), t, np.inf)
    ours = np.asarray(out.depth)
    assert agreement(ours, expect) >= 0.995
    # interpolated world position equals the ray hit (perspective-correct barycentrics)
    hit = np.isfinite(ours)
    pos = np.asarray(o) + ours[..., None] * np.asarray(d)
    np.testing.assert_allclose(np.asarray(out.color)[hit], pos[hit], atol=2e-3 * 100)
    np.testing.assert_allclose(np.asarray(out.color)[hit][:, 1], 0.0, atol=1e-3)


def test_perspective_correct_attributes(raster_jit):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    cam = look_at([0.5, 0.8, 3.0], [0, 0, 0], 40, 48, 36, 0.1, 50.0)
    v = np.asarray(mesh.vertices, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    out = raster_jit(cam, v, f, v)
    o, d = pixel_rays(cam, normalize=False)
    depth = np.asarray(out.depth)
    hit = np.isfinite(depth)
    pos = np.asarray(o) + depth[..., None] * np.asarray(d)
    np.testing.assert_allclose(np.asarray(out.color)[hit], pos[hit], atol=1e-4)
    b = np.asarray(out.bary)[hit]
    np.testing.assert_allclose(b.sum(-1), 1.0, atol=1e-5)
    assert b.min() > -1e-3
    assert np.all(np.asarray(out.tri_id)[~hit] == -1)


def test_backface_culling(raster_jit):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(mesh.vertices, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    cam = look_at([0, 0, 4.0], [0, 0, 0], 40, 32, 24, 0.1, 50.0)
    full = raster_jit(cam, v, f, v)
    culled = raster_jit(cam, v, f, v, cull_backfaces=True)
    np.testing.assert_array_equal(np.asarray(full.tri_id), np.asarray(culled.tri_id))
    inside_out = raster_jit(cam, v, f[:, ::-1].copy(), v, cull_backfaces=True)
    # only the far, inner side is left: it is behind the front of the sphere
    d_in = np.asarray(inside_out.depth)
    d_full = np.asarray(full.depth)
    hit = np.isfinite(d_full)
    assert np.all(d_in[hit] > d_full[hit])


def _same_frames(batched, single, k):
    """vmap path == loop path: identical triangle ids, depth/colour within 1e-5 relative."""
    for name in ("tri_id",):
        np.testing.assert_array_equal(getattr(batched, name)[k], getattr(single, name))
    for name in ("depth", "color", "bary"):
        b, s = np.asarray(getattr(batched, name)[k]), np.asarray(getattr(single, name))
        fin = np.isfinite(s)
        np.testing.assert_array_equal(np.isfinite(b), fin)
        # relative to each value, or to the frame's largest for values near zero
        scale = np.abs(s[fin]).max() if fin.any() else 1.0
        np.testing.assert_allclose(b[fin], s[fin], rtol=1e-5, atol=1e-5 * scale)


def test_vmap_over_cameras_and_posed_meshes_matches_loop_no_recompile(user_jit, compile_counter):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(mesh.vertices, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    cams = orbit_cameras([0, 0, 0], 3.0, 8, width=24, height=18)
    # A near plane cutting the sphere for one camera (clipped triangles in the batch too).
    # And one beyond it: an empty frame (on the CPU its shading is skipped) in the batch.
    cams = dataclasses.replace(cams, near=cams.near.at[3].set(2.8).at[5].set(4.5))
    by_cam = user_jit(jax.vmap(lambda c, vv: rasterize(c, vv, f, vv), (0, None)))
    single = user_jit(rasterize)
    out = by_cam(cams, v)
    assert np.mean(np.asarray(out.tri_id) >= 0) > 0.2
    assert np.all(np.asarray(out.tri_id[5]) == -1) and np.all(np.isinf(out.depth[5]))
    assert np.all(np.asarray(out.color[5]) == 0) and np.all(np.asarray(out.bary[5]) == 0)
    for k in range(8):
        one = jax.tree_util.tree_map(lambda x, k=k: x[k], cams)
        _same_frames(out, single(one, v, f, v), k)
    # Four posed meshes with shared faces, one camera.
    cam0 = jax.tree_util.tree_map(lambda x: x[0], cams)
    twist = np.array([0.0, 0.3, 0.6, 0.9], np.float32)
    c, s_ = np.cos(twist), np.sin(twist)
    posed = np.stack(
        [
            v @ np.array([[ci, 0, si], [0, 1, 0], [-si, 0, ci]], np.float32).T
            for ci, si in zip(c, s_)
        ]
    )
    by_pose = user_jit(jax.vmap(lambda vv: rasterize(cam0, vv, f, vv)))
    outp = by_pose(posed)
    for k in range(4):
        _same_frames(outp, single(cam0, posed[k], f, posed[k]), k)
    # The accelerators' rule forced on this CPU (one vectorized program for the batch, its
    # loops advancing every frame) gives the frame-by-frame frames.
    vec = dict(batching="vectorized")
    out_vec = user_jit(jax.vmap(lambda c: rasterize(c, v, f, v, **vec)))(cams)
    outp_vec = user_jit(jax.vmap(lambda vv: rasterize(cam0, vv, f, vv, **vec)))(posed)
    for k in range(8):
        _same_frames(out_vec, jax.tree_util.tree_map(lambda x, k=k: x[k], out), k)
    for k in range(4):
        _same_frames(outp_vec, jax.tree_util.tree_map(lambda x, k=k: x[k], outp), k)
    # A second batch of the same shapes (new cameras, moved vertices): no recompilation.
    cams2 = dataclasses.replace(
        cams, rotation=yaw_pitch_roll_rotation(cams.yaw + 7.0, cams.pitch, cams.roll)
    )
    with compile_counter() as compiles:
        jax.block_until_ready(by_cam(cams2, v + 0.05))
        jax.block_until_ready(by_pose(posed * 1.01))
    assert compiles.count == 0


def test_an_eager_call_runs_one_compiled_frame(raster_jit, compile_counter):
    # Called outside jit, rasterize and analytic_antialias run their frame as one compiled
    # program: a new camera of the same size compiles nothing (op by op, the z-buffer's and
    # the outline's loops compiled again at every call, seconds each), and the frame is the
    # jitted call's up to float rounding (the two programs fuse the faces' clamp apart).
    from jaxgfx.silhouette import analytic_antialias, silhouette_edges

    mesh = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(mesh.vertices, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    e = silhouette_edges(f)
    cams = orbit_cameras([0, 0, 0], 3.0, 2, width=24, height=18)
    c0, c1 = (jax.tree_util.tree_map(lambda x, k=k: x[k], cams) for k in range(2))
    eager = rasterize(c0, v, f, v)
    assert np.mean(np.asarray(eager.tri_id) >= 0) > 0.2
    _same_frames(jax.tree_util.tree_map(lambda x: x[None], raster_jit(c0, v, f, v)), eager, 0)
    aa = analytic_antialias(c0, v, f, eager, edges=e)
    assert np.abs(np.asarray(aa) - np.asarray(eager.color)).max() > 0.05  # outlines blended
    with compile_counter() as compiles:
        jax.block_until_ready(analytic_antialias(c1, v, f, rasterize(c1, v, f, v), edges=e))
    assert compiles.count == 0


def test_closed_form_shading_tangents_equal_autodiff_of_the_intersection():
    # The rasterizer's tangents (raster_tangents: M^-1 applied to the corners' bary-weighted
    # motion) against autodiff's JVP of its per-pixel ray-face intersection, for random
    # tangents of the vertices, the attributes and every float camera field (focal length
    # and principal point included), on a frame whose near plane cuts the sphere.
    from jaxgfx._src import raster as R
    from jaxgfx._src.camera import world_to_camera
    from jaxgfx._src.raster_tangents import shading_tangents

    mesh = trimesh.creation.icosphere(subdivisions=2)
    v = jnp.asarray(mesh.vertices, jnp.float32)
    f = jnp.asarray(mesh.faces, jnp.int32)
    rng = np.random.default_rng(0)
    attr = jnp.asarray(rng.normal(size=(v.shape[0], 2)), jnp.float32)
    cam = dataclasses.replace(
        look_at([1.4, 1.1, -2.3], [0.0, 0.0, 0.0], fov=45.0, width=24, height=18),
        near=jnp.float32(2.2),
    )
    out = rasterize(cam, v, f, attr)
    hit = np.asarray(out.tri_id) >= 0
    assert 0.2 < hit.mean() < 0.9
    face = jnp.where(hit.reshape(-1), out.tri_id.reshape(-1), R._NO_TRI)
    inv_depth = jnp.where(hit.reshape(-1), 1.0 / out.depth.reshape(-1), 0.0)

    def intersected(c, vv, a):
        return R._shade(c, world_to_camera(c, vv), f, a, inv_depth, face)

    def tangent_of(x):
        if not jnp.issubdtype(jnp.result_type(x), jnp.floating):
            return np.zeros(np.shape(x), jax.dtypes.float0)
        return jnp.asarray(rng.normal(size=np.shape(x)), jnp.float32)

    tangents = (jax.tree_util.tree_map(tangent_of, cam), tangent_of(v), tangent_of(attr))
    auto = jax.jit(lambda t: jax.jvp(intersected, (cam, v, attr), t)[1])(tangents)
    closed = jax.jit(lambda t: shading_tangents(cam, v, f, attr, *out[1:], *t))(tangents)
    for k in (0, 1, 3):  # colour, depth, barycentrics
        a, c = np.asarray(auto[k]), np.asarray(closed[k])
        assert np.abs(a).max() > 1.0  # tangents of every kind, not vacuous
        np.testing.assert_allclose(c, a, rtol=1e-4, atol=1e-4 * np.abs(a).max())
    assert closed[2].dtype == jax.dtypes.float0


def test_reverse_mode_through_vmap():
    # The custom_vmap z-buffer sits behind stop_gradient: grad of a vmapped render works
    # and equals the sum of the per-camera gradients.
    cam, v, f, colors = _grad_scene()
    cams = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), cam)
    turned = yaw_pitch_roll_rotation(cams.yaw + jnp.array([0.0, 4.0]), cams.pitch, cams.roll)
    cams = dataclasses.replace(cams, rotation=turned)

    def loss(vertices, c):
        out = rasterize(c, vertices, f, colors)
        return jnp.sum(jnp.where(out.tri_id >= 0, out.depth, 0.0)) + jnp.sum(out.color)

    g_vmap = jax.jit(jax.grad(lambda vv: jnp.sum(jax.vmap(lambda c: loss(vv, c))(cams))))(v)
    grad = jax.jit(jax.grad(loss))
    g_loop = sum(grad(v, jax.tree_util.tree_map(lambda x, k=k: x[k], cams)) for k in range(2))
    assert np.abs(np.asarray(g_loop)).max() > 0
    np.testing.assert_allclose(g_vmap, g_loop, rtol=1e-4, atol=1e-4)


def test_stacked_frames_visibility_matches_single(user_jit):
    # visibility(frames=B) (one B*H*W z-buffer) gives each frame's own result, bit for bit
    # (two programs: at the user's code generation).
    from jaxgfx._src.camera import world_to_camera_soa
    from jaxgfx._src.zbuffer import _frame_setup, visibility

    mesh = trimesh.creation.icosphere(subdivisions=1)
    v = jnp.asarray(mesh.vertices, jnp.float32)
    f = jnp.asarray(mesh.faces, jnp.int32)
    cams = [look_at([0.3, 0.2, 3.0], [0, 0, 0], 50, 16, 12, 0.1, 9.0),
            look_at([-2.0, 1.0, 2.0], [0, 0, 0], 50, 16, 12, 0.1, 9.0)]  # fmt: skip
    setup = jax.jit(lambda c: _frame_setup(c, v, f, False, 2, world_to_camera_soa(c, v)))
    setups = [setup(c) for c in cams]
    both = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b], -1), *setups)
    vis = user_jit(visibility, static_argnums=(2, 3, 4))
    inv2, fid2 = vis(cams[0], both, 2, 64, 2)
    for k, (c, s) in enumerate(zip(cams, setups, strict=True)):
        inv1, fid1 = vis(c, s, 2, 64, 1)
        np.testing.assert_array_equal(fid2.reshape(2, -1)[k], fid1)
        np.testing.assert_array_equal(inv2.reshape(2, -1)[k], inv1)


def test_face_batches_give_the_same_visibility(user_jit):
    # visible_faces(tri_batch=7): 80 faces set up and z-buffered 7 at a time (last batch
    # padded) -> the same ids and bit-identical 1/z as one batch; one camera's near plane
    # cuts the mesh (clipped second triangles keep their source face), with and without
    # back-face culling.
    from jaxgfx._src.zbuffer import NO_TRI, visible_faces

    run = user_jit(visible_faces, static_argnames=("cull_backfaces", "tri_batch"))
    mesh = trimesh.creation.icosphere(subdivisions=1)
    v = jnp.asarray(mesh.vertices, jnp.float32)
    f = jnp.asarray(mesh.faces, jnp.int32)
    for eye, near in (([0.3, 0.2, 3.0], 0.1), ([0.1, 0.2, 1.2], 0.3)):
        cam = look_at(eye, [0, 0, 0], 60, 24, 18, near, 9.0)
        for cull in (False, True):
            inv1, fid1 = run(cam, v, f, cull_backfaces=cull, tri_batch=1024)
            inv7, fid7 = run(cam, v, f, cull_backfaces=cull, tri_batch=7)
            assert np.count_nonzero(np.asarray(fid1) != NO_TRI) > 20
            np.testing.assert_array_equal(fid7, fid1)
            np.testing.assert_array_equal(inv7, inv1)


def test_shading_in_stripes_equals_whole_frame(monkeypatch):
    # Large frames are resolved and interpolated a stripe of rows at a time; forced here
    # on a small frame (4 stripes of 8 rows): the same images as in one piece.
    import jaxgfx._src.raster as raster

    mesh = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(mesh.vertices, np.float32)
    f = np.asarray(mesh.faces, np.int32)
    cam = look_at([0.4, 0.3, 2.5], [0, 0, 0], 50, 48, 32, 0.1, 9.0)
    assert raster._stripes(768, 1024) == 3 and raster._stripes(384, 512) == 1
    whole = raster.rasterize(cam, v, f, v)
    monkeypatch.setattr(raster, "_stripes", lambda h, w: 4)
    # A fresh compiled frame: the module's own has traced (and cached) the whole-frame rule.
    monkeypatch.setattr(raster, "_compiled_rasterize", jax.jit(raster._rasterize, static_argnums=0))
    parts = raster.rasterize(cam, v, f, v)
    assert np.count_nonzero(np.asarray(whole.tri_id) >= 0) > 200
    np.testing.assert_array_equal(parts.tri_id, whole.tri_id)
    # float rounding only (XLA contracts FMAs per fusion): the vmap tests' 1e-5; the
    # barycentrics of a pixel whose ray nearly grazes its face (small determinant) move a
    # few times more
    np.testing.assert_allclose(parts.depth, whole.depth, rtol=1e-5)
    np.testing.assert_allclose(parts.bary, whole.bary, atol=3e-5)
    np.testing.assert_allclose(parts.color, whole.color, rtol=1e-5, atol=1e-5)


def test_empty_and_offscreen_meshes(raster_jit):
    cam = camera_from_degrees([0, 0, 0], width=8, height=6)
    v = np.array([[0, 0, -5], [1, 0, -5], [0, 1, -5]], np.float32)  # behind the camera
    out = raster_jit(cam, v, np.array([[0, 1, 2]], np.int32), v)
    assert np.all(np.isinf(np.asarray(out.depth)))
    out = rasterize(cam, np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    assert out.depth.shape == (6, 8) and np.all(np.isinf(np.asarray(out.depth)))


@pytest.mark.parametrize(
    "vertices, faces, match",
    [
        (np.array([[0, 0, 1], [1, np.nan, 1], [0, 1, 1]], np.float32), [[0, 1, 2]], "finite"),
        (np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float32), [[0, 1, 3]], "out of range"),
        (np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float32), [[0, -1, 2]], "out of range"),
        (np.zeros((3, 2), np.float32), [[0, 1, 2]], "vertices"),
        (np.zeros((3, 3), np.float32), [[0, 1]], "faces"),
        (np.zeros((3, 3), np.float32), np.array([[0.0, 1.0, 2.0]]), "faces"),
    ],
)
def test_bad_mesh_input(vertices, faces, match):
    cam = camera_from_degrees([0, 0, 0], width=8, height=6)
    with pytest.raises((ValueError, TypeError), match=match):
        rasterize(cam, vertices, np.asarray(faces))


@pytest.mark.parametrize("devices", [0, 10**6, True, "cpu", [], ["cpu"]])
def test_bad_devices(devices):
    # Checked before tracing; the split itself is tested on 4 forced host devices
    # in test_sweep.py (bit-identical to one device, and under vmap).
    cam = camera_from_degrees([0, 0, 0], width=8, height=6)
    v, f = np.eye(3, dtype=np.float32) + [0, 0, 2], np.array([[0, 1, 2]], np.int32)
    with pytest.raises((ValueError, TypeError), match="devices"):
        rasterize(cam, v, f, devices=devices)


def test_bad_mesh_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        load_mesh(tmp_path / "missing.ply")
    bad = tmp_path / "bad.ply"
    bad.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1 2\n")
    with pytest.raises(ValueError, match="malformed|empty"):
        load_mesh(bad)
    garbage = tmp_path / "garbage.obj"
    garbage.write_text("this is not an obj file\n")
    with pytest.raises(ValueError):
        load_mesh(garbage)
    with pytest.raises(ValueError, match="suffix"):
        load_mesh(__file__)


def test_mesh_arrays_roundtrip(tmp_path):
    from jaxgfx.io import save_mesh

    m = trimesh.creation.icosphere(subdivisions=1)
    for suffix in (".ply", ".glb"):
        p = save_mesh(
            tmp_path / f"s{suffix}", m.vertices, m.faces, np.full((len(m.vertices), 3), 0.5)
        )
        back = load_mesh(p)
        v, f, c = mesh_arrays(back)
        assert v.shape == (len(m.vertices), 3) and f.shape == (len(m.faces), 3)
        np.testing.assert_allclose(np.sort(v, 0), np.sort(m.vertices, 0), atol=1e-5)
        assert c.shape == v.shape and np.all((c >= 0) & (c <= 1))
    assert not list(tmp_path.glob(".*tmp*"))
    _ = jnp


def _grad_scene():
    """Two non-coplanar triangles (a folded quad) filling most of a 16x12 frame, with colours."""
    v = np.array([[-2.0, -1.5, 0.0], [2.0, -1.5, 0.4], [2.0, 1.5, 0.0], [-2.0, 1.5, -0.3]])
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    colors = np.array([[1.0, 0.2, 0.1], [0.1, 0.9, 0.3], [0.2, 0.3, 1.0], [0.8, 0.8, 0.1]])
    cam = look_at([0.3, 0.2, 3.0], [0.0, 0.0, 0.0], 60, 16, 12, 0.1, 20.0)
    return cam, v.astype(np.float32), f, colors.astype(np.float32)


def test_gradients_match_finite_differences_on_interior_pixels():
    from jax.test_util import check_jvp, check_vjp

    cam, v, f, colors = _grad_scene()

    @jax.jit
    def render(vertices, position, rotation, attributes):
        c = dataclasses.replace(cam, position=position, rotation=rotation)
        out = rasterize(c, vertices, f, attributes)
        return out.depth, out.bary, out.color, out.tri_id

    # One compiled program serves every check: jax.linearize compiles the primal (with the
    # residuals) once; the tangent map and its transpose are small programs.  (check_grads
    # would compile the primal, its JVP and its VJP separately: ~3x the compile time.)
    args = (v, np.asarray(cam.position), np.asarray(cam.rotation), colors)
    ref = jax.linearize(render, *args)[0]
    tid = np.pad(np.asarray(ref[3]), 1, constant_values=-2)
    # Interior: covered, and all 8 neighbours see the same face, so an eps step (1e-3 world
    # units, ~1/100 pixel here) changes no pixel's face.
    same = np.ones(tid[1:-1, 1:-1].shape, bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            same &= (
                tid[1 + dy : tid.shape[0] - 1 + dy, 1 + dx : tid.shape[1] - 1 + dx]
                == (tid[1:-1, 1:-1])
            )
    interior = same & (tid[1:-1, 1:-1] >= 0)
    assert interior.sum() >= 40 and len(np.unique(np.asarray(ref[3])[interior])) == 2

    def visible(*a):  # depth, barycentrics and colours at the interior pixels
        out = render(*a)
        return out[0][interior], out[1][interior], out[2][interior]

    def primal(*a):
        return jax.linearize(visible, *a)[0]

    def f_jvp(primals, tangents):
        out, lin = jax.linearize(visible, *primals)
        return out, lin(*tangents)

    def f_vjp(*primals):
        out, lin = jax.linearize(visible, *primals)
        return out, jax.linear_transpose(lin, *primals)

    tol = dict(eps=1e-3, atol=2e-2, rtol=2e-2)
    check_jvp(primal, f_jvp, args, **tol)  # forward mode
    check_vjp(primal, f_vjp, args, **tol)  # reverse mode
    # The gradients are not zero (the check would pass vacuously), and the camera's is right:
    # moving the eye by t along its view axis moves the hit along each fixed pixel ray d on
    # the face's plane n.x = c by dz/dt = -(n . fwd) / (n . d).
    fwd = np.asarray(camera_basis(cam)[2], np.float32)
    zeros = [np.zeros_like(a) for a in args]
    d_depth = f_jvp(args, (zeros[0], fwd, zeros[2], zeros[3]))[1][0]
    d = np.asarray(pixel_rays(cam, normalize=False)[1], np.float64)[interior]
    tri = v[f[np.asarray(ref[3])[interior]]].astype(np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    np.testing.assert_allclose(d_depth, -(n @ fwd) / np.sum(n * d, -1), rtol=1e-4)


def test_count_le_matches_searchsorted():
    # The z-buffer's work item -> triangle search (_count_le) against NumPy's
    # searchsorted(side="right"): repeated offsets (triangles with no tiles), queries
    # before, between, on and past them, and lengths 1, a power of two and one past it.
    from jaxgfx._src.zbuffer import _count_le

    rng = np.random.default_rng(3)
    for n in (1, 2, 8, 9, 37):
        x = np.sort(rng.integers(0, 20, n)).astype(np.int32)
        q = np.arange(-2, 24, dtype=np.int32)
        got = jax.jit(_count_le)(jnp.asarray(x), jnp.asarray(q))
        np.testing.assert_array_equal(got, np.searchsorted(x, q, side="right"))
