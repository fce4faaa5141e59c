"""Per-plane RLE ray casting vs the per-pixel 3-D DDA reference (thesis 4.5)."""

from __future__ import annotations

import ast
import dataclasses
import functools
import importlib.util
import types
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from experiments.cast_rays import random_rays
from jaxgfx import raycast as RC
from jaxgfx import raycast as V
from jaxgfx._src.voxel import render as render_module
from jaxgfx._src.voxel import scatter, warp
from jaxgfx._src.voxel.scatter import scatter_limits
from jaxgfx._src.voxel.wide import traverse_wide
from jaxgfx.camera import (
    camera_basis,
    camera_from_degrees,
    camera_from_opencv,
    look_at,
    pixel_rays,
    project,
    stack_cameras,
    supersampled,
)

W, H = 96, 72
# Share of pixels (where either renderer hits) that must agree.
DEPTH_TOL = 1.0  # voxels
DEPTH_AGREE = 0.99
COLOR_AGREE = 0.98
# The thesis path alone (no per-pixel refinement, one plane per border pixel).
DEPTH_AGREE_PLAIN = 0.975
# render_rle's settings for the thesis method alone: one plane per border
# pixel (Eq. 4.4), nearest texel, no per-pixel re-walk.
THESIS = RC.RenderSettings(oversample=1.0, neighbors=0, refine_steps=0, planes_per_voxel=0.0)
# The wide traversal: the per-plane walk in blocks of cells (the renderer's walk for a
# map beyond the scatter's limits; the default draws these maps with the scatter).
WIDE = RC.RenderSettings(traversal="wide")


def _scene():
    X, Y, Z = 24, 20, 24
    g = np.indices((X, Y, Z)).transpose(1, 2, 3, 0) + 0.5
    occ = g[..., 1] < 2  # floor
    occ &= ~((g[..., 0] > 16) & (g[..., 2] < 8))  # a hole in the floor
    occ |= (np.abs(g[..., 0] - 7) < 3) & (g[..., 1] < 9) & (np.abs(g[..., 2] - 15) < 4)  # box
    occ |= np.sum((g - [16, 7, 15]) ** 2, axis=-1) < 16  # sphere
    occ |= (np.abs(g[..., 0] - 12) < 5) & (np.abs(g[..., 1] - 16) < 1) & (g[..., 2] < 10)  # roof
    x, y, z = np.indices((X, Y, Z))
    col = np.stack([(x * 37 + y * 11) % 256, (y * 53 + z * 29) % 256, (z * 71 + x * 13) % 256], -1)
    return V.dense_to_voxels(occ, col.astype(np.uint8))


@pytest.fixture(scope="module")
def user_render(user_jit):
    """``render_rle`` called eagerly, its compiled frame compiled at the user's code generation
    (as a user's process compiles it; the suite compiles at its own), for the module's tests:
    one program per settings, which each test would otherwise compile again."""
    frame = user_jit(render_module._compiled_frame.__wrapped__, static_argnums=0)

    def eager(*args, **kwargs):
        suites = render_module._compiled_frame  # swapped for this call only: jit refuses
        render_module._compiled_frame = frame  # compiler options on a nested jit
        try:
            return RC.render_rle(*args, **kwargs)
        finally:
            render_module._compiled_frame = suites

    return eager


@pytest.fixture(scope="module")
def scene():
    vox = _scene()
    occ, col = V.voxels_to_dense(vox)
    rle = V.as_jax(V.encode_rle(vox, levels=2))
    return vox, rle, jnp.asarray(occ), jnp.asarray(col)


CAMERAS = [
    ("level", camera_from_degrees([12, 5, -14], 10, 0, 0, 60, W, H)),
    ("down", look_at([12.2, 40, 11.7], [12, 0, 12], fov=60, width=W, height=H)),
    ("oblique", look_at([40, 25, 38], [12, 5, 12], fov=55, width=W, height=H)),
    ("below", look_at([-10, -8, 30], [12, 10, 12], fov=60, width=W, height=H)),
    ("inside", camera_from_degrees([3, 12, 20], 135, -25, 0, 70, W, H)),
]

# One entry per trace of `render`: a new entry means a new compilation.
_TRACES: list[None] = []


def _render_traced(*args, **kwargs):
    _TRACES.append(None)
    return RC.render_rle(*args, **kwargs)


render = jax.jit(_render_traced)
reference = jax.jit(RC.reference_render, static_argnames=("max_steps",))


def _agreement(out, ref):
    d1, d2 = np.asarray(out.depth), np.asarray(ref.depth)
    h1, h2 = np.isfinite(d1), np.isfinite(d2)
    union = h1 | h2
    dd = np.abs(np.where(h1, d1, 0) - np.where(h2, d2, 0))
    depth_ok = (h1 == h2) & (~h1 | (dd <= DEPTH_TOL))
    col_ok = (h1 == h2) & np.all(np.abs(np.asarray(out.color) - np.asarray(ref.color)) < 1e-3, -1)
    return depth_ok[union].mean(), col_ok[union].mean(), union.sum()


def _slow_first_hit(occ, o, d):
    """Brute force: slab-intersect the ray with every solid voxel."""
    best, vox = np.inf, None
    for v in np.argwhere(occ):
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (v - o) / d
            t1 = (v + 1 - o) / d
        lo = np.nanmax(np.minimum(t0, t1))
        hi = np.nanmin(np.maximum(t0, t1))
        if lo <= hi and hi >= 0 and max(lo, 0) < best:
            best, vox = max(lo, 0), v
    return best, vox


def test_dda_ray_3d_matches_bruteforce():
    rng = np.random.default_rng(0)
    occ = rng.random((6, 5, 7)) < 0.08
    col = rng.integers(0, 256, (6, 5, 7, 3)).astype(np.uint8)
    fn = jax.jit(
        jax.vmap(
            lambda o, d: RC.dda_ray_3d(
                jnp.asarray(occ), jnp.asarray(col), o, d, max_steps=21, far=1e4
            )
        )
    )
    o = rng.uniform(-3, 9, (64, 3)).astype(np.float32)
    target = rng.uniform(0, 5, (64, 3)).astype(np.float32)
    d = (target - o).astype(np.float32)
    rgb, t, vox = (np.asarray(a) for a in fn(o, d))
    for k in range(64):
        if (
            occ[tuple(np.floor(o[k]).astype(int))]
            if np.all((o[k] >= 0) & (o[k] < occ.shape))
            else False
        ):
            continue  # origin inside a solid voxel: undefined first hit
        tb, vb = _slow_first_hit(occ, o[k].astype(np.float64), d[k].astype(np.float64))
        if np.isinf(tb):
            assert np.isinf(t[k])
        else:
            assert t[k] == pytest.approx(tb, abs=1e-4)
            assert occ[tuple(vox[k])]
            np.testing.assert_allclose(rgb[k], col[tuple(vox[k])] / 255.0, atol=1e-6)


def _jaxgfx_imports(module: str) -> dict[str, set[str]]:
    """The jaxgfx modules ``module`` imports (by its source), each with the names it takes."""
    spec = importlib.util.find_spec(module)
    assert spec is not None and spec.origin is not None, module
    package = module if spec.submodule_search_locations else module.rpartition(".")[0]
    found: dict[str, set[str]] = {}
    for node in ast.walk(ast.parse(Path(spec.origin).read_text())):
        if isinstance(node, ast.Import):
            for alias in node.names:
                found.setdefault(alias.name, set())
        elif isinstance(node, ast.ImportFrom):
            name = node.module or ""
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                name = f"{base}.{name}" if name else base
            found.setdefault(name, set()).update(alias.name for alias in node.names)
    return {m: names for m, names in found.items() if m.split(".")[0] == "jaxgfx"}


def test_reference_imports_nothing_from_the_renderer():
    # The reference checks the renderer only if it runs none of the renderer's code: a
    # helper both shared (the DDA's set-up once was) would be wrong in both alike.  It may
    # take the camera's pixel rays (the rays every renderer and peer is compared on) and
    # the result type, nothing else of the package.
    renderer: set[str] = set()
    todo = ["jaxgfx._src.voxel.render"]
    while todo:  # the frame's modules: render and everything it imports, transitively
        module = todo.pop()
        if module not in renderer:
            renderer.add(module)
            todo += _jaxgfx_imports(module)
    assert {"jaxgfx._src.voxel.grid", "jaxgfx._src.voxel.warp"} < renderer
    allowed = {
        "jaxgfx._src.camera": {"Camera", "pixel_rays"},
        "jaxgfx._src.voxel.settings": {"RenderOutput"},
    }
    for module, names in _jaxgfx_imports("jaxgfx._src.voxel.reference").items():
        assert module in allowed, f"the reference imports {sorted(names)} from {module}"
        assert names <= allowed[module], f"the reference imports {sorted(names)} from {module}"


cast = jax.jit(RC.cast_rays)


@functools.partial(jax.jit, static_argnames=("max_steps",))
def dda_rays(occ, col, origins, directions, *, max_steps):
    one = functools.partial(RC.dda_ray_3d, max_steps=max_steps, far=np.inf)
    return jax.vmap(one, in_axes=(None, None, 0, 0))(occ, col, origins, directions)


@pytest.mark.parametrize("instances", [False, True], ids=["volume", "instance-map"])
def test_cast_rays_meet_the_reference_ddas_voxels(scene, instances):
    # cast_rays walks the pointer map's columns and meets their runs; the reference walks the
    # dense grid voxel by voxel (Amanatides & Woo).  On random rays from outside and inside
    # the box: the same hit or miss and the same voxel, t and colour to float rounding; the
    # normal is the face the hit point lies on, facing the ray; far cuts hits beyond it.
    vox, rle, occ, col = scene
    if instances:
        tiles = [[0, 0], [1, 1], [0, 1], [2, 0]]
        inst = V.place_instances(V.encode_rle(vox, levels=2, mips="column"), tiles, (3, 3))
        rle = V.as_jax(inst)
        occ, col = (jnp.asarray(a) for a in V.voxels_to_dense(V.decode_rle(inst)))
    o, d = random_rays(rle.shape, 4000, seed=int(instances))
    hits = cast(rle, o, d)
    ref = dda_rays(occ, col, o, d, max_steps=sum(occ.shape) + 3)
    rgb, t, voxel = (np.asarray(a) for a in ref)
    ht, hv, hn = np.asarray(hits.t), np.asarray(hits.voxel), np.asarray(hits.normal)
    assert 0.3 < np.isfinite(t).mean() < 0.8
    assert np.mean(np.isfinite(ht) == np.isfinite(t)) >= 0.999
    assert np.mean(np.all(hv == voxel, -1)) >= 0.999
    both = np.isfinite(ht) & np.all(hv == voxel, -1)
    np.testing.assert_allclose(ht[both], t[both], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(hits.color)[both], rgb[both], atol=1e-6)
    assert np.all(hv[~np.isfinite(ht)] == -1) and np.all(hn[~np.isfinite(ht)] == 0)
    # A face normal (one signed axis) where the ray enters the voxel, 0 where it starts in it.
    entered = both & (ht > 0)
    assert np.all(np.abs(hn[entered]).sum(-1) == 1) and np.all(hn[both & (ht == 0)] == 0)
    axis = np.argmax(np.abs(hn[entered]), -1)[:, None]
    point = np.take_along_axis(o[entered] + ht[entered, None] * d[entered], axis, 1)
    face = np.take_along_axis(hv[entered] + (hn[entered] > 0), axis, 1)
    np.testing.assert_allclose(point, face, atol=1e-3)
    assert np.all(np.sum(hn[entered] * d[entered], -1) < 0)
    near = cast(rle, o, d, far=10.0)
    np.testing.assert_array_equal(np.isfinite(np.asarray(near.t)), np.isfinite(ht) & (ht <= 10))


def test_an_opencv_camera_sees_what_its_rays_meet(scene):
    # A COLMAP-like camera (fx != fy, principal point off centre, rolled) through the
    # per-plane method: its vanishing point, segments and plane rows.  The depth is that of
    # 4000 of its pixels' rays written from K, R and t alone, cast by cast_rays (checked
    # against the reference DDA above).
    from experiments.camera_models import opencv_intrinsics, opencv_look_at, opencv_pixel_rays

    _, rle, _, _ = scene
    K = opencv_intrinsics(W, H, 60.0)
    R, t = opencv_look_at([27.0, 17.0, -5.0], [12.0, 3.0, 12.0], roll=11.0)
    cam = camera_from_opencv(K, R, t, W, H, near=0.05, far=1e4)
    depth = np.asarray(render(rle, cam).depth)
    o, d = opencv_pixel_rays(K, R, t, W, H)
    pick = np.random.default_rng(0).choice(W * H, 4000, replace=False)
    hits = cast(rle, *(jnp.asarray(a.reshape(-1, 3)[pick], jnp.float32) for a in (o, d)))
    ref, ours = np.asarray(hits.t), depth.reshape(-1)[pick]
    assert 0.3 < np.isfinite(ref).mean() < 0.95
    both = np.isfinite(ref) & np.isfinite(ours)
    gap = np.abs(np.where(both, ours, 0.0) - np.where(both, ref, 0.0))
    same = (np.isfinite(ref) == np.isfinite(ours)) & (gap <= DEPTH_TOL)
    assert same.mean() >= 0.995, same.mean()


def test_frame_normals_are_the_faces_cast_rays_enters(scene):
    # hit_normals reads the face each pixel's hit lies on from render_rle's depth; cast_rays
    # on the same pixels' rays gives the face it enters: the same on >= 99 % of the pixels
    # both hit (the rest: rays through a grid edge, and pixels the two draw apart).
    _, rle, _, _ = scene
    for name in ("oblique", "inside"):
        cam = dict(CAMERAS)[name]
        out = render(rle, cam)
        normals = np.asarray(RC.hit_normals(cam, out.depth))
        origins, directions = pixel_rays(cam, normalize=False)
        hits = cast(rle, origins.reshape(-1, 3), directions.reshape(-1, 3))
        entered = np.abs(np.asarray(hits.normal)).sum(-1).reshape(H, W) > 0
        both = np.isfinite(np.asarray(out.depth)) & entered
        assert both.sum() > 1000, name
        same = np.all(normals == np.asarray(hits.normal).reshape(H, W, 3), -1)
        assert same[both].mean() >= 0.99, (name, same[both].mean())
        assert np.all(normals[~np.isfinite(np.asarray(out.depth))] == 0)
    with pytest.raises(ValueError, match="depth must have the camera's shape"):
        RC.hit_normals(cam, out.depth[1:])


def test_cast_rays_batch_shapes_and_bad_rays(scene):
    _, rle, _, _ = scene
    o, d = random_rays(rle.shape, 12, seed=2)
    flat = cast(rle, o, d)
    grid = RC.cast_rays(rle, o.reshape(3, 4, 3), d.reshape(3, 4, 3))
    assert grid.t.shape == (3, 4) and grid.voxel.shape == (3, 4, 3)
    np.testing.assert_array_equal(np.asarray(grid.voxel).reshape(12, 3), flat.voxel)
    # vmap over batches of rays: the flat batch's hits
    batched = jax.vmap(RC.cast_rays, in_axes=(None, 0, 0))(
        rle, o.reshape(3, 4, 3), d.reshape(3, 4, 3)
    )
    np.testing.assert_array_equal(np.asarray(batched.voxel).reshape(12, 3), flat.voxel)
    np.testing.assert_array_equal(np.asarray(batched.t).reshape(12), flat.t)
    with pytest.raises(ValueError, match="origins must have shape"):
        RC.cast_rays(rle, o[:, :2], d)
    with pytest.raises(ValueError, match="same shape"):
        RC.cast_rays(rle, o, d[:5])
    with pytest.raises(ValueError, match="directions must be nonzero"):
        RC.cast_rays(rle, o, np.zeros_like(d))
    with pytest.raises(ValueError, match="origins: values must be finite"):
        RC.cast_rays(rle, np.full_like(o, np.nan), d)


def test_vanishing_point_cases():
    cam = camera_from_degrees([0, 5, 0], 30, -20, 0, 60, W, H)
    vp = np.asarray(RC.vanishing_point(cam))
    # The screen image of the downward vertical through the eye (Eq. 4.2, 4.3).

    xy, depth = project(cam, jnp.array([0.0, -1.0, 0.0]))
    assert depth > 0
    np.testing.assert_allclose(vp[:2] / vp[2], np.asarray(xy), rtol=1e-4)
    level = RC.vanishing_point(camera_from_degrees([0, 5, 0], 30, 0, 0, 60, W, H))
    assert float(level[2]) == pytest.approx(0.0, abs=1e-7)  # vp at infinity
    assert np.all(np.isfinite(np.asarray(level)))
    down = RC.vanishing_point(camera_from_degrees([0, 5, 0], 0, -90, 0, 60, W, H))
    np.testing.assert_allclose(np.asarray(down[:2] / down[2]), [W / 2, H / 2], atol=1e-3)


def test_segment_plane_counts_eq_4_4():
    # vp at the screen centre: np_i = 2 dist(vp, border_i) -> H, H, W, W.
    cam = camera_from_degrees([0, 5, 0], 0, -90, 0, 60, W, H)
    seg = RC.screen_segments(cam, RC.vanishing_point(cam), num_planes=RC.default_num_planes(W, H))
    np.testing.assert_allclose(np.asarray(seg.count), [H, H, W, W], atol=1)
    # Level camera: everything is one segment of about W planes.
    cam = camera_from_degrees([0, 5, 0], 0, 0, 0, 60, W, H)
    seg = RC.screen_segments(cam, RC.vanishing_point(cam), num_planes=RC.default_num_planes(W, H))
    c = np.asarray(seg.count)
    assert sorted(c)[:3] == [0, 0, 0] and abs(c.max() - W) <= 1


@pytest.mark.parametrize("name,cam", CAMERAS, ids=[c[0] for c in CAMERAS])
def test_matches_reference_dda(scene, name, cam):
    vox, rle, occ, col = scene
    RC.check_camera_outside(rle, cam)
    ref, _ = reference(occ, col, cam)
    out = render(rle, cam)  # the defaults the acceptance is measured with
    d_ok, c_ok, n = _agreement(out, ref)
    assert n > 800, f"{name}: too few hit pixels for a meaningful test"
    assert d_ok >= DEPTH_AGREE, f"{name}: depth agreement {d_ok:.4f}"
    assert c_ok >= COLOR_AGREE, f"{name}: colour agreement {c_ok:.4f}"
    plain = render(rle, cam, settings=THESIS)
    d_ok, c_ok, _ = _agreement(plain, ref)
    assert d_ok >= DEPTH_AGREE_PLAIN, f"{name}: thesis-path depth agreement {d_ok:.4f}"
    for o in (out, plain):
        assert np.all(np.isfinite(np.asarray(o.color)))
        assert not np.any(np.isnan(np.asarray(o.depth)))
        assert int(o.stats["buffer_overflow"]) == 0
        # The scatter's counts (the default here, a single-object map): (element,
        # plane) pairs, the rows they project to, the texels drawn.
        st = {k: int(v) for k, v in o.stats.items()}
        assert 0 < st["elements_rendered"] <= st["elements_processed"]
        assert 0 < st["elements_total"] <= st["elements_processed"] + st["elements_total"] // 2


def test_half_width_pixels_match_reference(scene):
    # The thesis's 2x1 AA frame: the same view on pixels half as wide.  Every
    # step of the per-plane method (vp, segments, plane extents, Eq. 4.5 rows,
    # the warp) must use the horizontal focal length; the reference DDA
    # shoots its rays through pixel_rays.
    _, rle, occ, col = scene
    for name, cam in CAMERAS[:3]:
        half = dataclasses.replace(cam, width=W // 2, principal=cam.principal * jnp.array([0.5, 1]))
        fine = supersampled(half, (2, 1))
        assert fine.shape == (H, W) and float(fine.pixel_aspect) == 0.5
        xy, _ = project(fine, fine.position + jnp.array([0.0, -1.0, 0.0]))
        vp = np.asarray(RC.vanishing_point(fine))
        if abs(vp[2]) > 1e-3:
            np.testing.assert_allclose(vp[:2] / vp[2], np.asarray(xy), rtol=1e-4, atol=1e-3)
        ref, _ = reference(occ, col, fine)
        d_ok, c_ok, n = _agreement(render(rle, fine), ref)
        assert n > 800, name
        assert d_ok >= DEPTH_AGREE, f"{name}: depth agreement {d_ok:.4f}"
        assert c_ok >= COLOR_AGREE, f"{name}: colour agreement {c_ok:.4f}"


def test_vmap_over_cameras_bit_identical_and_no_recompile(
    scene, compile_counter, user_jit, user_render
):
    # vmap renders the views one after another (render_rle's custom_vmap rule),
    # so a batch of 8 is the loop's frames bit for bit, and new cameras of the
    # same size compile nothing, batched or not.  (At full size, in a process with
    # XLA's default flags: python -m experiments.vmap_identity.)
    _, rle, _, _ = scene
    cams = [c for _, c in CAMERAS] + [
        look_at([30 + 4 * k, 18, -6 + 9 * k], [12, 4, 12], fov=55, width=W, height=H)
        for k in range(3)
    ]
    batched_fn = user_jit(jax.vmap(RC.render_rle, in_axes=(None, 0)))
    batched = batched_fn(rle, stack_cameras(cams))
    # A loop of eager calls (each runs render_rle's compiled frame).
    for k, cam in enumerate(cams):
        single = user_render(rle, cam)
        np.testing.assert_array_equal(np.asarray(batched.depth[k]), np.asarray(single.depth))
        np.testing.assert_array_equal(np.asarray(batched.color[k]), np.asarray(single.color))
        assert int(batched.stats["planes"][k]) == int(single.stats["planes"])
    moved = [dataclasses.replace(c, position=c.position + 0.25) for c in cams]
    stacked = stack_cameras(moved)  # (eager ops compile too: outside the count)
    with compile_counter() as counter:
        batched_fn(rle, stacked)
        user_render(rle, moved[0])
        user_render(rle, moved[4])
    assert counter.count == 0


def test_lod_level_matches_downsampled_reference(scene):
    vox, rle, _, _ = scene
    # With a tiny LOD distance every column after the first is read from mip 1,
    # which equals the reference through the 2x down-sampled grid, scaled by 2.
    cam = look_at([40, 25, 38], [12, 5, 12], fov=55, width=W, height=H)
    out = render(rle, cam, lod_distance=1e-3)
    small = V.downsample_voxels(vox)
    occ1, col1 = (jnp.asarray(a) for a in V.voxels_to_dense(small))
    half = cam.__class__(**{**cam.__dict__, "position": cam.position / 2})
    ref, _ = reference(occ1, col1, half)
    d1, d2 = np.asarray(out.depth), 2 * np.asarray(ref.depth)
    both = np.isfinite(d1) & np.isfinite(d2)
    union = np.isfinite(d1) | np.isfinite(d2)
    agree = both & (np.abs(np.where(both, d1, 0.0) - np.where(both, d2, 0.0)) <= 2.0)
    assert agree.sum() / union.sum() >= 0.9


def test_column_mips_join_lod_bands_without_steps():
    # A one-voxel ground slab (an instance map of 4 x 4 tiles) is the same surface at every
    # level of column mips, so with LOD bands from 6 voxels out the frame equals the level-0
    # frame, on both traversals.  Cube mips raise it by up to 2^l - 1 voxels where each
    # band starts: the seam lines of a forest's ground.
    occ = np.zeros((32, 4, 32), bool)
    occ[:, 0] = True
    col = np.zeros(occ.shape + (3,), np.uint8)
    col[..., 1] = 200
    vox = V.dense_to_voxels(occ, col, surface=False)
    cam = look_at([-6.0, 5.0, -6.0], [40.0, 0.0, 40.0], fov=60, width=W, height=H, far=1e4)
    tiles = [(i, j) for i in range(4) for j in range(4)]
    for mips, settings in (("column", None), ("column", WIDE), ("cube", None)):
        rle = V.as_jax(V.place_instances(V.encode_rle(vox, levels=4, mips=mips), tiles, (4, 4)))
        kw = {} if settings is None else dict(settings=settings)
        full = render(rle, cam, lod_distance=np.inf, **kw)
        banded = render(rle, cam, lod_distance=6.0, **kw)
        d0, d1 = np.asarray(full.depth), np.asarray(banded.depth)
        assert np.isfinite(d0).mean() > 0.2
        both = np.isfinite(d0) & np.isfinite(d1)
        moved = np.abs(np.where(both, d1 - d0, 0.0)) / np.where(both, d0, 1)
        if mips == "column":
            # the map's far edge: a few pixels sampled by other planes
            assert np.mean(np.isfinite(d1) != np.isfinite(d0)) < 2e-3
            # equal depth but on a few pixels, mostly on the slab's outline (next to the
            # sky), up to about half a voxel, where the ray buffer samples another plane
            # (at most one pixel more: which plane wins there follows the compiler's
            # rounding)
            assert np.mean(moved[both] < 1e-3) > 0.99 and np.sum(moved > 0.03) <= 1
            assert moved.max() < 0.1
            same = np.all(np.asarray(banded.color) == np.asarray(full.color), axis=-1)
            assert same[both].mean() > 0.995
        else:
            assert np.mean(moved > 0.05) > 0.2  # the steps this test exists to catch


@pytest.mark.parametrize("pixels", [1.0, 2.5])
def test_lod_distance_for_sizes_a_band_start_cell_in_pixels(pixels):
    # Where each band starts (lod * 2 ** (l - 1)) a cell of 2 ** l voxels, across
    # the view axis, projects to `pixels` pixels along the larger focal length.
    eye = np.array([5.0, 7.0, 3.0])
    for cam, axis in [
        (look_at(eye, eye + [0, 0, 1], fov=50, width=W, height=H), 1),
        (supersampled(look_at(eye, eye + [0, 0, 1], fov=50, width=W, height=H), (2, 1)), 0),
    ]:
        lod = float(RC.lod_distance_for(cam, pixels))
        for level in (1, 3):
            d, size = lod * 2 ** (level - 1), 2.0**level
            ends = eye + np.array([[0, 0, d], [0, 0, d]]) + np.eye(3)[axis] * [[0], [size]]
            xy, _ = project(cam, jnp.asarray(ends, jnp.float32))
            assert abs(float(xy[1, axis] - xy[0, axis])) == pytest.approx(pixels, rel=1e-4)
    batch = stack_cameras([cam, dataclasses.replace(cam, focal=cam.focal * 2)])
    both = jax.jit(jax.vmap(lambda c: RC.lod_distance_for(c, pixels)))(batch)
    assert both.shape == (2,) and float(both[1]) > float(both[0])
    for bad, err in [(0.0, ValueError), (-1.0, ValueError), ("1", TypeError)]:
        with pytest.raises(err, match="pixels"):
            RC.lod_distance_for(cam, bad)


def _relief(n=80, h=20):
    """A height field whose every column differs: 1-voxel ledges everywhere."""
    rng = np.random.default_rng(0)
    x, z = np.mgrid[0:n, 0:n]
    top = (h / 2 + h / 4 * np.sin(x / 7) * np.cos(z / 5) + rng.integers(0, h // 3, (n, n))).astype(
        int
    )
    occ = np.arange(h)[None, :, None] < top[:, None, :]
    g = np.indices(occ.shape)
    col = np.stack([(g[0] * 37 + g[1] * 11) % 256, (g[1] * 53 + g[2] * 29) % 256, g[2] * 3], -1)
    return V.dense_to_voxels(occ, col.astype(np.uint8))


def test_far_view_finds_columns_narrower_than_a_pixel():
    # 160 voxels away a voxel is ~0.4 pixel, so a plane per
    # half pixel misses columns (thesis spacing: 89 % depth, 82 % colour).
    # The planes fitted to the scene, a third of a voxel apart at its far end,
    # keep the acceptance.
    vox = _relief()
    occ, col = (jnp.asarray(a) for a in V.voxels_to_dense(vox))
    c = np.array([40.0, 10.0, 40.0])
    d = np.array([np.sin(0.5), 0.5, np.cos(0.5)])
    cam = look_at(c + 160 * d / np.linalg.norm(d), c, fov=40, width=64, height=48, far=1e5)
    out = jax.jit(RC.render_rle)(V.encode_rle(vox), cam)
    ref, _ = reference(occ, col, cam)
    d_ok, c_ok, n = _agreement(out, ref)
    assert n > 500, n
    assert d_ok >= DEPTH_AGREE, f"depth agreement {d_ok:.4f}"
    assert c_ok >= COLOR_AGREE, f"colour agreement {c_ok:.4f}"
    assert int(out.stats["planes"]) > 4 * (64 + 48), "planes not densified for the far view"


def test_empty_scene_and_camera_inside():
    vox = V.Voxels(np.zeros((0, 3), np.int32), np.zeros((0, 3), np.uint8), (8, 8, 8))
    rle = V.as_jax(V.encode_rle(vox))
    cam = look_at([20, 10, 20], [4, 4, 4], fov=60, width=16, height=12)
    out = jax.jit(RC.render_rle)(rle, cam)
    assert np.all(np.isinf(np.asarray(out.depth)))
    assert np.all(np.asarray(out.color) == 0)
    full = V.dense_to_voxels(np.ones((4, 4, 4), bool), np.full((4, 4, 4, 3), 9, np.uint8))
    with pytest.raises(ValueError, match="inside a solid voxel"):
        RC.check_camera_outside(V.encode_rle(full), look_at([0.5, 3.5, 2.5], [9, 9, 9]))


def test_instances_render_like_copies(scene):
    vox, rle, _, _ = scene
    inst = V.place_instances(V.encode_rle(vox, levels=2), [[0, 0], [1, 1], [0, 1]], (2, 2))
    occ, col = (jnp.asarray(a) for a in V.voxels_to_dense(V.decode_rle(inst)))
    cam = look_at([55, 28, 50], [24, 5, 24], fov=55, width=W, height=H)
    ref, _ = reference(occ, col, cam)
    out = render(V.as_jax(inst), cam, settings=WIDE)
    d_ok, c_ok, n = _agreement(out, ref)
    # The wide walk's pixels on the tiles' outlines follow the last bits of the camera's
    # rotation: 99.6 % agree at the users' code generation, 99.0 % at the tests' level 0.
    assert n > 800 and d_ok >= 0.985 and c_ok >= 0.985, (d_ok, c_ok)


def test_scatter_draws_an_instance_map_over_8192_columns_wide():
    # A row of 1,100 tiles of an 8-column object: 8,800 columns along x, past 2^13, so the
    # packed map cells need their 14 bits; the view looks down on the row's far end.
    occ = np.zeros((8, 6, 32), bool)
    occ[:, 0] = True  # ground
    occ[2:5, 1:5, 12:16] = True  # a post
    col = np.zeros(occ.shape + (3,), np.uint8)
    col[..., 0] = np.arange(8)[:, None, None] * 30
    col[..., 1] = 160
    vox = V.dense_to_voxels(occ, col, surface=False)
    n = 1100
    inst = V.place_instances(V.encode_rle(vox, levels=1), [(i, 0) for i in range(n)], (n, 1))
    rle = V.as_jax(inst)
    assert inst.shape[0] == 8 * n and scatter_limits(rle, 4096) is None
    cam = look_at([8520.0, 24.0, -10.0], [8540.0, 0.0, 16.0], fov=50, width=W, height=H, far=1e4)
    out = render(rle, cam, settings=SCATTER)
    occ_m, col_m = (jnp.asarray(a) for a in V.voxels_to_dense(V.decode_rle(inst)))
    # Every ray leaves the map or meets the ground within about 200 cells: 400 DDA steps
    # give the default's frame (8,843 steps: ten times the test's time).
    ref, _ = reference(occ_m, col_m, cam, max_steps=400)
    d_ok, c_ok, hits = _agreement(out, ref)
    assert hits > 0.3 * W * H
    assert d_ok >= DEPTH_AGREE and c_ok >= COLOR_AGREE, (d_ok, c_ok)


def test_scatter_plane_runs_past_32767_planes_read_back_unsigned(scene):
    # An element's plane runs are one packed word, n1 | lo1 << 16, whose top bit is lo1's
    # once a map needs 32,768 planes or more (the 1600-bunny map needs 61,248): cutting the
    # runs to a pass's planes must read lo1 back unsigned.  Against the runs as sets.
    rng = np.random.default_rng(3)
    lo1 = rng.integers(0, 60000, 256)
    lo1[:4] = [32767, 32768, 60000, 0]
    n1 = rng.integers(0, 5000, 256)
    n2 = rng.integers(0, 300, 256)
    word = jnp.asarray(n1 | (lo1 << 16), jnp.uint32).view(jnp.int32)
    el = types.SimpleNamespace(planes=word, n_pairs=jnp.asarray(n1 + n2, jnp.int32))
    for p_lo, p_hi in [(0, 65535), (32000, 40000), (50000, 65535), (100, 200)]:
        n_pairs, runs = scatter._pass_planes(el, jnp.int32(p_lo), jnp.int32(p_hi))
        runs = np.asarray(runs).view(np.uint32)
        m1, a1 = runs & 0xFFFF, runs >> 16
        want1 = np.maximum(np.minimum(lo1 + n1, p_hi) - np.maximum(lo1, p_lo), 0)
        want2 = np.maximum(np.minimum(n2, p_hi) - p_lo, 0)
        np.testing.assert_array_equal(m1, want1)
        np.testing.assert_array_equal(np.asarray(n_pairs), np.where(n1 + n2 > 0, want1 + want2, 0))
        np.testing.assert_array_equal(a1[want1 > 0], np.maximum(lo1, p_lo)[want1 > 0])
    _, rle, _, _ = scene
    assert scatter_limits(rle, 65535) is None and scatter_limits(rle, 65536) is not None


def test_even_oversample_keeps_pixel_aligned_planes(scene):
    # Level camera: vp at infinity, planes are screen columns.  With an even
    # oversample every other plane must still pass through a pixel centre
    # (Segments.phase), so the nearest-texel image equals the 1-plane-per-pixel
    # one instead of sampling a quarter pixel off (which would move pixels all
    # over the frame).  Two programs, at the suite's code generation: the top row
    # is held apart (there a plane's row range, w ~ 0, may round either way, and
    # two of its pixels differ).
    _, rle, _, _ = scene
    cam = CAMERAS[0][1]
    one = render(rle, cam, settings=THESIS)
    even = RC.RenderSettings(oversample=2.0, neighbors=0, refine_steps=0, planes_per_voxel=0.0)
    two = render(rle, cam, settings=even)
    d1, d2 = np.asarray(two.depth), np.asarray(one.depth)
    assert np.isfinite(d2).mean() > 0.2
    np.testing.assert_allclose(d1[1:], d2[1:], rtol=1e-5)
    np.testing.assert_array_equal(np.asarray(two.color)[1:], np.asarray(one.color)[1:])
    assert np.sum(~np.isclose(d1[0], d2[0], rtol=1e-5) & ~(np.isinf(d1[0]) & np.isinf(d2[0]))) <= 2


def test_encoded_volume_closed_over_under_jit(scene):
    # The natural first try: encode inside the jitted function (NumPy buffers closed over,
    # constants of the program) gives the frame of the as_jax path (up to the rounding of
    # two programs: XLA folds the constants into the first).
    vox, rle, _, _ = scene
    cam = CAMERAS[2][1]
    closed = jax.jit(lambda c: RC.render_rle(V.encode_rle(vox, levels=2), c))(cam)
    passed = render(rle, cam)
    d1, d2 = np.asarray(closed.depth), np.asarray(passed.depth)
    assert np.isfinite(d2).mean() > 0.1
    assert _same_depth(d1, d2) >= 0.995
    assert np.mean(np.all(np.asarray(closed.color) == np.asarray(passed.color), -1)) >= 0.995


def test_warp_lists_searches_from_each_words_first_entry(scene):
    # The warp finds a texel's writer by scanning its plane's list front to back for
    # the first element covering the row, from the first entry that drew in the row's
    # coverage word: against a loop over the lists, and against the scan from each
    # list's head (the same frame).
    _, rle, _, _ = scene
    cam = CAMERAS[2][1]
    P = RC.default_num_planes(W, H, 2.0)
    seg = RC.screen_segments(cam, RC.vanishing_point(cam), num_planes=P, oversample=2.0)

    @jax.jit
    def both(rle, cam, seg):
        lists = traverse_wide(rle, cam, seg, jnp.arange(P), rows=W, lod_distance=jnp.inf)
        pool, start, drawn, cov, first = lists[:5]
        b = warp.warp_lists(rle, cam, seg, pool, start, drawn, cov, first, tile=16)
        b0 = warp.warp_lists(rle, cam, seg, pool, start, drawn, cov, tile=16)
        return b, b0, pool, start, drawn, first

    b, b0, pool, start, drawn, first = both(rle, cam, seg)
    lists = [np.asarray(pool)[:, a : a + n] for a, n in zip(np.asarray(start), np.asarray(drawn))]
    # Each coverage word's first drawing entry: the first of its plane's list whose
    # rows [r0, r1) meet the word, none for an empty word.
    want = np.full(np.asarray(first).shape, 2**31 - 1)
    for p, rows in enumerate(lists):
        for e, w in reversed(list(enumerate(rows[0]))):
            r0, r1 = w & 0xFFFF, w >> 16
            want[p, r0 >> 5 : ((r1 - 1) >> 5) + 1] = e
    np.testing.assert_array_equal(np.asarray(first), want)
    assert (want < 2**31 - 1).sum() > 50
    assert 0.1 < np.isfinite(np.asarray(b[1])).mean() < 0.5
    # The same writers (colours, entered); depths up to the two programs' rounding.
    np.testing.assert_array_equal(np.asarray(b[0]), np.asarray(b0[0]))
    np.testing.assert_array_equal(np.asarray(b[2]), np.asarray(b0[2]))
    np.testing.assert_allclose(np.asarray(b[1]), np.asarray(b0[1]), rtol=1e-6)


def test_far_plane_spacing_follows_the_lod_cell():
    # A big instance map seen from its corner: spacing planes a third of a
    # level-0 voxel apart at the far corner would take thousands of planes,
    # though mip cells there are 2^l voxels wide; with LOD the density follows
    # the cell size, and without LOD (or for a near box) nothing changes.
    cam = look_at([-38, 70, -38], [-37, 69.65, -37], 55, W, H, far=1e5)
    vp = RC.vanishing_point(cam)

    def count(shape, **kw):
        P = RC.default_num_planes(W, H, 2.0, scene_shape=shape, planes_per_voxel=3.0)
        seg = RC.screen_segments(cam, vp, num_planes=P, oversample=2.0, scene_shape=shape, **kw)
        return int(np.sum(np.asarray(seg.count)))

    big, near = (2560, 64, 2560), (24, 20, 24)
    dense = count(big, planes_per_voxel=3.0)
    lod = count(big, planes_per_voxel=3.0, lod_distance=96.0, levels=7)
    thesis = count(big, planes_per_voxel=0.0)
    assert thesis <= lod < dense / 3, (thesis, lod, dense)
    assert count(near, planes_per_voxel=3.0) == count(
        near, planes_per_voxel=3.0, lod_distance=96.0, levels=7
    )


def test_live_rows_keep_every_row_that_can_still_meet_the_scene():
    # A plane stops once its undrawn rows can no longer meet 0 <= y <= top past
    # the walk's t (eye above the scene, rows above the horizon or between the
    # crowns of an instance map).  Brute force per row from its own slope: no
    # row that can still meet the slab is left out, and the bound is tight (a
    # row kept that cannot is within one row of the range's ends).
    from jaxgfx._src.voxel.walk import _live_rows, _plane_init

    cam = look_at([-10, 26, -12], [40, 14, 50], 55, W, H, far=1e5)
    seg = RC.screen_segments(cam, RC.vanishing_point(cam), num_planes=64)
    rle = dataclasses.replace(V.encode_rle(_scene()), shape=(96, 20, 96))
    ey, top, ts = 26.0, 20.0, jnp.asarray([1.0, 15.0, 40.0, 90.0])

    @jax.jit
    def rows_and_slopes(ts):
        planes = jnp.arange(64)
        init = lambda p: _plane_init(rle, cam, seg, p, rows=W, n_words=-(-W // 32))  # noqa: E731
        consts, _ = jax.vmap(init)(planes)
        pp = jax.vmap(lambda p: RC.plane_parameters(cam, seg, p, rows=W))(planes)
        fy = camera_basis(cam)[2][1]
        live = jax.vmap(lambda q, t: _live_rows(q, jnp.float32(ey), t, y_top=top, fy=fy))
        a0, a1 = jax.vmap(lambda t: live(consts, jnp.broadcast_to(t, (64,))))(ts)
        return a0, a1, pp.row_slope, pp.valid, pp.lo, pp.hi, consts.t_far

    out = [np.asarray(a) for a in rows_and_slopes(ts)]
    a0s, a1s, slope, valid, lo, hi, t_far = out
    slope, rows = slope.astype(np.float64), np.arange(W)[None, :]
    lo, hi, t_far = lo[:, None], hi[:, None], t_far.astype(np.float64)[:, None]
    kept = 0
    for t, a0, a1 in zip(np.asarray(ts, np.float64), a0s, a1s):
        a0, a1 = a0[:, None], a1[:, None]
        y_near, y_far = ey + slope * t, ey + slope * np.maximum(t_far, t)
        meets = valid & (np.maximum(y_near, y_far) >= 0) & (np.minimum(y_near, y_far) <= top)
        inside = (rows >= a0) & (rows < a1)
        # (A plane's first and last rows are drawn only as far as an element's
        # slope clipped to the plane's range projects onto them; so are these.)
        assert not np.any(meets & ~inside & (rows > lo) & (rows < hi - 1))
        loose = valid & inside & ~meets & (rows > a0) & (rows < a1 - 1)
        assert not np.any(loose)
        kept += int(np.sum(meets))
    assert kept > 1000 and int(np.sum(valid)) * 4 > kept  # rows were dropped


# ---------------------------------------------------------------------------
# The wide traversal (a block of cells per plane per loop step) and its batching
# ---------------------------------------------------------------------------

WIDE_VECTOR = RC.RenderSettings(traversal="wide", batching="vectorized")
WIDE_CAMERAS = [CAMERAS[1], CAMERAS[2], CAMERAS[4]]


def test_a_map_beyond_the_scatters_limits_takes_the_wide_walk(scene):
    # The test scene in a grid 4,100 voxels high, past the scatter's 4,096: the default
    # draws it with the wide walk, with 512 plane slots where lowered for the CPU (the
    # same frame as asking for them) and every plane in every step for CUDA and TPU,
    # and agrees with the per-pixel DDA (rays meet the scene within 160 of its cells).
    from jax import export

    vox, _, occ, col = scene
    X, Y, Z = vox.shape
    tall = V.make_voxels(vox.coords, vox.colors, (X, 4100, Z))
    rle = V.as_jax(V.encode_rle(tall, levels=2))
    assert "4096 voxels high" in scatter_limits(rle, 1000)
    occ_t = jnp.zeros((X, 4100, Z), bool).at[:, :Y].set(occ)
    col_t = jnp.zeros((X, 4100, Z, 3), col.dtype).at[:, :Y].set(col)
    slots = RC.RenderSettings(traversal="wide", slots=512)
    for k, (name, cam) in enumerate((CAMERAS[2], CAMERAS[4])):
        out = render(rle, cam)
        ref, _ = reference(occ_t, col_t, cam, max_steps=160)
        d_ok, c_ok, n = _agreement(out, ref)
        assert n > 800 and d_ok >= DEPTH_AGREE and c_ok >= COLOR_AGREE, (name, d_ok, c_ok)
        assert int(out.stats["buffer_overflow"]) == 0, name
        if k == 0:
            # The slots' form: the same frame and loop steps (its warp scans one list
            # entry a step; every plane in every step scans 8: 28 steps here, not 48).
            asked = render(rle, cam, settings=slots)
            np.testing.assert_array_equal(np.asarray(asked.depth), np.asarray(out.depth))
            np.testing.assert_array_equal(np.asarray(asked.color), np.asarray(out.color))
            steps = int(out.stats["loop_iterations"])
            assert steps == int(asked.stats["loop_iterations"]), steps
    fn = jax.jit(lambda c: RC.render_rle(rle, c).depth)
    assert export.export(fn, platforms=("cuda", "tpu"))(CAMERAS[2][1]).platforms == ("cuda", "tpu")


def test_wide_traversal_matches_reference_and_batches_as_one_program(scene):
    # Every plane walks a block of cells per loop step: the agreement with the
    # per-pixel DDA in tens of dependent steps (the thesis's one-cell walk takes
    # thousands).
    _, rle, occ, col = scene
    per = []
    for name, cam in WIDE_CAMERAS:
        ref, _ = reference(occ, col, cam)
        # lod_distance passed as the scatter tests pass it: the same compiled program.
        out = render(rle, cam, settings=WIDE, lod_distance=np.float32(np.inf))
        per.append(out)
        d_ok, c_ok, n = _agreement(out, ref)
        assert n > 800, name
        assert d_ok >= DEPTH_AGREE, f"{name}: depth agreement {d_ok:.4f}"
        assert c_ok >= COLOR_AGREE, f"{name}: colour agreement {c_ok:.4f}"
        st = {k: int(v) for k, v in out.stats.items()}
        assert st["buffer_overflow"] == 0
        assert st["elements_rendered"] <= st["elements_processed"] <= st["elements_total"]
        assert 0 < st["traversal_steps"] <= 20, (name, st["traversal_steps"])
        assert st["loop_iterations"] <= 60, (name, st["loop_iterations"])
    # The accelerator's vmap rule (one vmapped program: the cameras' planes form
    # one wider array) against the frames rendered one by one, both run here.
    # Batched float arithmetic may round a plane's set-up differently, so a few
    # edge pixels may flip; depths agree to 1e-6.
    stacked = stack_cameras([c for _, c in WIDE_CAMERAS])
    vec = jax.jit(jax.vmap(lambda c: RC.render_rle(rle, c, settings=WIDE_VECTOR)))(stacked)
    steps = [int(o.stats["loop_iterations"]) for o in per]
    for k, single in enumerate(per):
        d1, d2 = np.asarray(vec.depth[k]), np.asarray(single.depth)
        both = np.isfinite(d1) & np.isfinite(d2)
        assert np.mean(np.isfinite(d1) == np.isfinite(d2)) >= 0.995
        rel = np.abs(d1[both] - d2[both]) / np.maximum(d2[both], 1.0)
        assert np.mean(rel <= 1e-6) >= 0.995
        assert int(vec.stats["loop_iterations"][k]) == steps[k]
    # A batch's dependent steps: about its slowest frame's, not their sum.
    assert max(steps) < 0.5 * sum(steps)


# ---------------------------------------------------------------------------
# The scatter traversal (every element into the planes that cross its cell)
# ---------------------------------------------------------------------------

SCATTER = RC.RenderSettings(traversal="scatter")


def _same_depth(d1, d2):
    """Share of pixels with the same depth up to a few ulps (both missed counts as the same)."""
    return np.mean(np.isclose(d1, d2, rtol=1e-5, atol=0) | (np.isinf(d1) & np.isinf(d2)))


def test_scatter_traversal_draws_the_per_plane_walks_frames(scene, user_render):
    # The first writer of a texel is fixed by the walk's order alone, so
    # projecting every element into the planes that cross its cell and keeping
    # each texel's smallest walk-order key gives the per-plane walk's ray buffer
    # (the wide traversal's: the walk in blocks of cells): the same frames, in a
    # few wide steps.  A window of 96 pairs and a table
    # of 8 ray-buffer columns walk the pairs in many steps and many passes (runs
    # of planes in turn) and must give the same frame.
    _, rle, occ, col = scene
    small = dataclasses.replace(SCATTER, window=96, texels=8 * W)
    # The default settings draw this map with the scatter (within its limits; the
    # steps and re-walk checks below fail for the wide traversal), in the vmap test's
    # program.  lod_distance passed to `render` every time: one program per traversal
    # for both parts.
    inf = np.float32(np.inf)
    walks, rewalked = {}, []
    for name, cam in CAMERAS:
        # The user's code generation: the windows' frames below are compared bit for bit.
        out = user_render(rle, cam)
        walk = walks[name] = render(rle, cam, settings=WIDE, lod_distance=inf)
        ref, _ = reference(occ, col, cam)
        d_ok, c_ok, n = _agreement(out, ref)
        assert n > 800, name
        assert d_ok >= DEPTH_AGREE and c_ok >= COLOR_AGREE, (name, d_ok, c_ok)
        # The same frame up to float rounding: each traversal sets its planes up
        # in its own program (depths a few ulps apart), and a row at a plane's
        # slope limit (straight down from the eye) can fall either side of a
        # pixel centre.
        d1, d2 = np.asarray(out.depth), np.asarray(walk.depth)
        assert _same_depth(d1, d2) >= 0.99, (name, _same_depth(d1, d2))
        assert np.mean(np.all(np.asarray(out.color) == np.asarray(walk.color), -1)) >= 0.99
        st = {k: int(v) for k, v in out.stats.items()}
        # A few wide steps: windows of pairs, their rows a window at a time.
        assert 1 <= st["traversal_steps"] <= 8, (name, st)
        assert st["elements_total"] >= int(walk.stats["elements_processed"]) > 0
        # The scatter's warp needs no re-walk (RenderSettings.refine_steps); the
        # walk's lists keep theirs.
        assert st["refined"] == 0, (name, st)
        rewalked.append(int(walk.stats["refined"]))
        many = user_render(rle, cam, settings=small)
        np.testing.assert_array_equal(np.asarray(many.depth), d1)
        np.testing.assert_array_equal(np.asarray(many.color), np.asarray(out.color))
        assert int(many.stats["traversal_steps"]) > 4 * st["traversal_steps"], name
        assert int(many.stats["passes"]) > max(4, st["passes"]), name
    assert max(rewalked) > 0, rewalked
    # Mip level 1 from 8 voxels on.  The scatter switches a plane's level where the
    # thesis's one-cell walk does, at the exit of the first cell past the band's
    # start; the wide traversal at the first major-axis column past it, so the bands
    # of the two may start a column apart (a short band here: 1.1 % of the pixels
    # differ, at the bands' ends).
    for name, cam in (CAMERAS[2], CAMERAS[4]):
        out = render(rle, cam, settings=SCATTER, lod_distance=np.float32(8.0))
        walk = render(rle, cam, settings=WIDE, lod_distance=np.float32(8.0))
        d1, d2 = np.asarray(out.depth), np.asarray(walk.depth)
        assert not np.array_equal(d2, np.asarray(walks[name].depth))
        assert _same_depth(d1, d2) >= 0.98, (name, _same_depth(d1, d2))


def _dda_level_starts(ex, ez, hx, hz, t0, t_far, lod, shape, levels):
    """Float64 NumPy: where one plane's 2-D DDA enters each mip level (4.5.4.1), cell by cell.

    The thesis's walk: from its first cell, it leaves level ``l`` at the exit of the first
    cell that it leaves past ``lod 2^l``, into the parent of the cell across that exit.
    """
    X, Z = shape
    t_lev, lev = [t0], 0
    ix = int(np.clip(np.floor(ex + hx * t0), 0, X - 1))
    iz = int(np.clip(np.floor(ez + hz * t0), 0, Z - 1))
    while len(t_lev) < levels:
        band, c = lod * 2.0**lev, 2.0**lev
        if band >= t_far:
            t_lev.append(t_far)
            lev, ix, iz = lev + 1, ix >> 1, iz >> 1
            continue
        nx = ((ix + (hx > 0)) * c - ex) / hx if abs(hx) >= 1e-12 else np.inf
        nz = ((iz + (hz > 0)) * c - ez) / hz if abs(hz) >= 1e-12 else np.inf
        t_out = min(nx, nz, t_far)
        if nx <= nz:
            ix += 1 if hx > 0 else -1
        else:
            iz += 1 if hz > 0 else -1
        if t_out >= band:
            lev, ix, iz = lev + 1, ix >> 1, iz >> 1
            t_lev.append(min(max(t_out, t_lev[-1]), t_far))
        elif t_out >= t_far:
            t_lev += [t_far] * (levels - len(t_lev))
    return t_lev


def test_scatter_level_starts_follow_each_planes_dda(scene):
    # The scatter pairs a cell with a plane only over the plane's stretch at the cell's
    # mip level; the stretches' starts are computed per plane in closed form.  Against
    # each plane's DDA walked cell by cell in float64 (bands from 4 voxels on, three
    # levels): cameras outside the map switch at their first cells' exits, the one
    # inside at the bands' ends.
    from jaxgfx._src.voxel.scatter_planes import _plane_tables

    vox = scene[0]
    rle = V.as_jax(V.encode_rle(vox, levels=3))
    L, lod = rle.levels, 4.0
    s = RC.RenderSettings()  # the default plane densities
    P = RC.default_num_planes(
        W, H, s.oversample, scene_shape=rle.shape, planes_per_voxel=s.planes_per_voxel
    )

    @jax.jit
    def tables(cam):
        seg = RC.screen_segments(
            cam,
            RC.vanishing_point(cam),
            num_planes=P,
            oversample=s.oversample,
            scene_shape=rle.shape,
            planes_per_voxel=s.planes_per_voxel,
            lod_distance=lod,
            levels=L,
        )
        pl = _plane_tables(rle, cam, seg, jnp.arange(P), rows=W, lod=jnp.float32(lod))
        return pl.packed, pl.angle

    checked = 0
    for name, cam in CAMERAS:
        packed, angle = (np.asarray(a, np.float64) for a in tables(cam))
        ex, ez = float(cam.position[0]), float(cam.position[2])
        for row in packed[np.isfinite(angle)]:
            # Columns: hx, hz, 7 more constants, then t_level (levels + 1, last t_far).
            t_level = row[9 : 9 + L + 1]
            want = _dda_level_starts(
                ex, ez, row[0], row[1], t_level[0], t_level[-1], lod, rle.shape[::2], L
            )
            np.testing.assert_allclose(t_level[:L], want, rtol=1e-4, atol=1e-3, err_msg=name)
            checked += 1
    assert checked > 1000


def test_scatter_traversal_batches_and_lowers_for_accelerators(scene):
    # One vmapped program renders the batch's frames together (their planes and
    # pairs form wider arrays), agreeing with the frames rendered one by one;
    # the program lowers for CUDA and TPU.
    from jax import export

    _, rle, _, _ = scene
    cams = [c for _, c in WIDE_CAMERAS]
    vector = dataclasses.replace(SCATTER, batching="vectorized")
    fn = jax.jit(jax.vmap(lambda c: RC.render_rle(rle, c, settings=vector)))
    stacked = stack_cameras(cams)
    vec = fn(stacked)
    for k, cam in enumerate(cams):
        single = render(rle, cam, settings=SCATTER, lod_distance=np.float32(np.inf))
        d1, d2 = np.asarray(vec.depth[k]), np.asarray(single.depth)
        both = np.isfinite(d1) & np.isfinite(d2)
        assert np.mean(np.isfinite(d1) == np.isfinite(d2)) >= 0.995
        rel = np.abs(d1[both] - d2[both]) / np.maximum(d2[both], 1.0)
        assert np.mean(rel <= 1e-6) >= 0.995
    # The batch just run: its trace is reused, only the lowerings are new.
    exported = export.export(fn, platforms=("cuda", "tpu"))(stacked)
    assert exported.platforms == ("cuda", "tpu")


def test_scatter_window_fills_an_accelerator(scene):
    # On the CPU a window of pairs is half the frame's pixels, its rows drawn a
    # window at a time; on an accelerator, where every loop step is a launch and
    # a host sync, four times the pixels, with four windows of rows a step, and
    # each frame of a vectorized batch keeps it up to 2^23 pairs a step for the
    # batch (so the batch takes its slowest frame's steps).  The program lowered
    # for CUDA carries the accelerator's window (its rows: 4 windows).
    from jax import export

    from jaxgfx._src.voxel.scatter import default_window, rows_per_pair

    assert default_window(512, 384) == 1 << 17
    assert (rows_per_pair(), rows_per_pair(accelerator=True)) == (1, 4)
    assert default_window(512, 384, accelerator=True) == 1 << 20
    assert default_window(512, 384, accelerator=True, frames=8) == 1 << 20
    assert default_window(512, 384, accelerator=True, frames=32) == 1 << 18  # 2^23 a batch
    assert default_window(64, 48, accelerator=True, frames=64) == 1 << 14
    assert default_window(3840, 2160, accelerator=True) == 1 << 22  # bounded memory
    assert default_window(3840, 2160, accelerator=True, frames=4) == 1 << 21
    assert default_window(8, 8, accelerator=True, frames=4096) == 1 << 14
    with pytest.raises(ValueError, match="frames"):
        default_window(8, 8, frames=0)
    _, rle, _, _ = scene
    fn = jax.jit(lambda c: RC.render_rle(rle, c, settings=SCATTER))
    rows = f"tensor<{4 * default_window(W, H, accelerator=True)}x"
    assert default_window(W, H, accelerator=True) > default_window(W, H)
    for platform, window in (("cuda", True), ("cpu", False)):
        text = export.export(fn, platforms=(platform,))(CAMERAS[2][1]).mlir_module()
        assert (rows in text) == window, platform
    # A vectorized batch of 4 keeps a frame's window: its program's row arrays
    # are the frame's, batched.
    lone = default_window(W, H, accelerator=True)
    assert default_window(W, H, accelerator=True, frames=4) == lone
    batch = jax.jit(jax.vmap(lambda c: RC.render_rle(rle, c, settings=SCATTER)))
    four = stack_cameras([c for _, c in CAMERAS[:4]])
    assert f"tensor<4x{4 * lone}x" in (
        export.export(batch, platforms=("cuda",))(four).mlir_module()
    )


INSTANCE_CAMERAS = [
    ("across", look_at([-6.0, 30.0, -4.0], [40.0, 4.0, 36.0], fov=60, width=W, height=H)),
    ("inside", camera_from_degrees([36, 14, 30], 45, -25, 0, 70, W, H)),
]


def test_scatter_draws_instance_maps_as_the_walk_and_batches_them():
    # An instance map's elements are drawn per tile at the tile's mip level,
    # gathered near tiles first in chunks: the per-plane walk's frame (the walk
    # agrees with the per-pixel DDA on instance maps:
    # test_instances_render_like_copies), at every LOD, whatever the chunk,
    # window and table sizes.  A vectorized batch agrees with the frames one by
    # one and lowers for CUDA and TPU.
    from jax import export

    tiles = [[0, 0], [1, 1], [0, 1], [2, 0], [2, 2], [1, 2]]
    inst = V.place_instances(V.encode_rle(_scene(), levels=2, mips="column"), tiles, (3, 3))
    rle = V.as_jax(inst)
    frames = {}
    for name, cam in INSTANCE_CAMERAS:
        for lod in (np.inf, 10.0):
            out = render(rle, cam, settings=SCATTER, lod_distance=np.float32(lod))
            walk = render(rle, cam, settings=WIDE, lod_distance=np.float32(lod))
            d1, d2 = np.asarray(out.depth), np.asarray(walk.depth)
            assert np.isfinite(d1).mean() > 0.3, name
            # (With LOD the two may start a band a column apart: see
            # test_scatter_traversal_draws_the_per_plane_walks_frames.)
            agree = 0.99 if np.isinf(lod) else 0.98
            assert _same_depth(d1, d2) >= agree, (name, lod, _same_depth(d1, d2))
            same_color = np.all(np.asarray(out.color) == np.asarray(walk.color), -1)
            assert np.mean(same_color) >= agree, (name, lod)
            st = {k: int(v) for k, v in out.stats.items()}
            # a few wide steps (the frame's pairs fill 4 windows)
            assert 1 <= st["traversal_steps"] <= 16, (name, st)
            frames[name, lod] = (out, st)
    # Many chunks, windows and passes: the same frame up to rounding (another
    # program rounds depths a few ulps apart, and a pixel at a box's edge may
    # then take the re-walk, whose budget this frame overflows).
    small = dataclasses.replace(SCATTER, chunk=64, window=96, texels=8 * W)
    cam, lod = INSTANCE_CAMERAS[0][1], np.float32(10.0)
    one, st = frames[INSTANCE_CAMERAS[0][0], 10.0]
    many = render(rle, cam, settings=small, lod_distance=lod)
    assert _same_depth(np.asarray(many.depth), np.asarray(one.depth)) >= 0.995
    same_color = np.all(np.asarray(many.color) == np.asarray(one.color), -1)
    assert np.mean(same_color) >= 0.995
    assert int(many.stats["traversal_steps"]) > 4 * st["traversal_steps"]
    cams = [c for _, c in INSTANCE_CAMERAS]
    vector = dataclasses.replace(SCATTER, batching="vectorized")
    fn = jax.jit(jax.vmap(lambda c: RC.render_rle(rle, c, settings=vector, lod_distance=lod)))
    vec = fn(stack_cameras(cams))
    for k, (name, _) in enumerate(INSTANCE_CAMERAS):
        d1, d2 = np.asarray(vec.depth[k]), np.asarray(frames[name, 10.0][0].depth)
        both = np.isfinite(d1) & np.isfinite(d2)
        assert np.mean(np.isfinite(d1) == np.isfinite(d2)) >= 0.995
        rel = np.abs(d1[both] - d2[both]) / np.maximum(d2[both], 1.0)
        assert np.mean(rel <= 1e-6) >= 0.995
    exported = export.export(fn, platforms=("cuda", "tpu"))(stack_cameras(cams))
    assert exported.platforms == ("cuda", "tpu")


def test_scatter_traversal_rejects_what_it_cannot_draw(scene):
    with pytest.raises(ValueError, match="texels must be at least two ray-buffer columns"):
        RC.render_rle(scene[1], CAMERAS[2][1], settings=dataclasses.replace(SCATTER, texels=W))


@functools.partial(jax.jit, static_argnames=("slots",))
def _wide_lists(rle, cam, slots):
    n = RC.default_num_planes(W, H, 2.0, scene_shape=rle.shape, planes_per_voxel=3.0)
    seg = RC.screen_segments(
        cam, RC.vanishing_point(cam), num_planes=n, oversample=2.0, scene_shape=rle.shape,
        planes_per_voxel=3.0,
    )  # fmt: skip
    planes = jnp.arange(n, dtype=jnp.int32)
    return traverse_wide(rle, cam, seg, planes, rows=W, lod_distance=jnp.inf, slots=slots)


def test_plane_slots_draw_the_same_lists(scene, user_jit):
    # 40 planes at a time, each done plane's slot taking the next queued plane:
    # the lists of every plane stepping in every step, with narrower steps.  The same
    # bits is a claim about two programs, so both compile as users' programs do (at the
    # tests' level 0 the two fuse a plane's set-up differently: a few packed rows moved).
    _, rle, _, _ = scene
    cam = CAMERAS[2][1]
    every = user_jit(lambda r, c: _wide_lists(r, c, None))(rle, cam)
    slots = user_jit(lambda r, c: _wide_lists(r, c, 40))(rle, cam)
    for a, b in zip(every[:-1], slots[:-1]):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert int(np.sum(every[2])) > 1000
    assert int(slots[-1]) > int(every[-1])


def test_depth_gradient_wrt_camera_matches_finite_differences(scene):
    # The traversal's choices carry no gradient; each hit pixel's depth carries
    # its ray's entry into the voxel it hit.  Looking down on the scene, the eye
    # rises by 0.25 voxels (hits move across pixel centres): on the pixels whose
    # hit stays on its face (depth moved by less than half a voxel) the finite
    # difference of the summed depth is the gradient.
    _, rle, _, _ = scene
    cam = CAMERAS[1][1]

    def total(y, mask):
        d = RC.render_rle(rle, dataclasses.replace(cam, position=cam.position.at[1].set(y))).depth
        return jnp.sum(jnp.where(mask & jnp.isfinite(d), d, 0.0))

    y0, dy = cam.position[1], 0.25
    depth = np.asarray(render(rle, cam).depth)
    moved = np.asarray(
        render(rle, dataclasses.replace(cam, position=cam.position.at[1].add(dy))).depth
    )
    both = np.isfinite(depth) & np.isfinite(moved)
    diff = np.where(both, moved - depth, np.inf)
    keep = both & (np.abs(diff) < 0.5)
    assert keep.sum() > 0.8 * both.sum()
    grad = float(jax.jit(jax.grad(total))(y0, jnp.asarray(keep)))
    fd = float(np.sum(diff[keep])) / dy
    assert np.isfinite(grad) and fd > 0.5 * keep.sum()
    assert abs(grad - fd) <= 0.02 * abs(fd), (grad, fd)
