"""``jaxgfx.checked``: value checks that hold under ``jit``, and none in the default programs.

Each kernel is compiled once with its checks (a module-level ``checked(jax.jit(...))``) and
run on one bad input per case: the checks run with the program, so the cases share it.
"""

from __future__ import annotations

import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from test_inputs import _lbs_args

import jaxgfx
from jaxgfx import raycast, skin
from jaxgfx.camera import Camera, look_at
from jaxgfx.raster import rasterize
from jaxgfx.silhouette import analytic_antialias, silhouette_edges

SPHERE = trimesh.creation.icosphere(subdivisions=1)
V = np.asarray(SPHERE.vertices, np.float32)  # 42 vertices
F = np.asarray(SPHERE.faces, np.int32)  # 80 faces
CAM = look_at([0.4, 0.3, 3.0], [0, 0, 0], 50.0, 16, 12, 0.1, 9.0)
NAN = np.float32(np.nan)

raster_checked = jaxgfx.checked(jax.jit(rasterize))


def _cam(**fields):
    return dataclasses.replace(CAM, **{k: jnp.asarray(v, jnp.float32) for k, v in fields.items()})


def _nan_at(a, index):
    a = np.array(a, copy=True)
    a[index] = np.nan
    return a


RASTER_CASES = {
    "NaN vertices": (
        (CAM, _nan_at(V, (np.s_[3:6], 1)), F, V),
        "vertices: 3 of 126 values are NaN or infinite (in rasterize)",
    ),
    "a face index past the vertices": (
        (CAM, V, np.where(np.arange(F.size).reshape(F.shape) == 7, 1532, F), V),
        "faces: index 1532 out of range for 42 vertices (in rasterize)",
    ),
    "a negative face index": (
        (CAM, V, np.where(np.arange(F.size).reshape(F.shape) == 7, -2, F), V),
        "faces: index -2 out of range for 42 vertices",
    ),
    "NaN attributes": ((CAM, V, F, _nan_at(V, (0, 0))), "attributes: 1 of 126 values"),
    "NaN camera position": (
        (_cam(position=[0.4, NAN, 3.0]), V, F, V),
        "cam.position: 1 of 3 values are NaN or infinite (in rasterize)",
    ),
    "NaN camera rotation": (
        (_cam(rotation=[1.0, 0.0, NAN, 0.0]), V, F, V),
        "cam.rotation: 1 of 4 values",
    ),
    "zero rotation": ((_cam(rotation=[0.0] * 4), V, F, V), "cam.rotation: has norm 0.0"),
    "NaN focal length": ((_cam(focal=[NAN, 40.0]), V, F, V), "cam.focal: 1 of 2 values are NaN"),
    "negative focal length": ((_cam(focal=[40.0, -4.0]), V, F, V), "cam.focal: -4.0 must be > 0"),
    "near <= 0": ((_cam(near=-1.0), V, F, V), "cam.near: -1.0 must be > 0"),
    "far <= near": ((_cam(far=0.05), V, F, V), "cam.far: 0.05 must be > near"),
}


@pytest.mark.parametrize("case", sorted(RASTER_CASES))
def test_checked_rasterize_names_a_bad_traced_value(case):
    args, message = RASTER_CASES[case]
    with pytest.raises(ValueError, match=re.escape(message)):
        raster_checked(*args)


def test_good_input_renders_the_same_frame_checked_or_not(raster_jit):
    out = raster_checked(CAM, V, F, V)
    ref = raster_jit(CAM, V, F, V)
    np.testing.assert_array_equal(np.asarray(out.tri_id), ref.tri_id)
    # Another program: XLA may fuse the camera's rotation and the shading otherwise, an
    # ulp here and there.
    np.testing.assert_allclose(np.asarray(out.depth), ref.depth, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(out.bary), ref.bary, rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(out.color), ref.color, rtol=0, atol=1e-6)
    # Without checked the same bad values pass under jit: the checks are opt-in.
    bad = np.where(np.arange(F.size).reshape(F.shape) == 7, 1532, F)
    assert np.isfinite(np.asarray(raster_jit(CAM, V, bad, V).depth)).any()


def test_default_programs_hold_no_check():
    def lowered(fn, *args):
        return jax.jit(fn).lower(*args).as_text()

    def lbs(t):
        return skin.linear_blend_skinning(t, *LBS_ARGS[1:])

    # Lowering only: which callbacks a program holds is decided while tracing.
    for fn, args in ((rasterize, (CAM, V, F)), (lbs, (LBS_ARGS[0],))):
        assert "callback" not in lowered(fn, *args)
        inside: list[str] = []
        jaxgfx.checked(lambda *a, fn=fn, got=inside: got.append(lowered(fn, *a)))(*args)
        assert inside[0].count("callback") >= 3


def test_a_batch_of_cameras_names_the_bad_one():
    # vmap over cameras: the renderer's batch rule (frame by frame, vectorized elsewhere)
    cams = jaxgfx.stack_cameras([CAM, _cam(near=-1.0), CAM])
    render = jaxgfx.checked(jax.jit(jax.vmap(rasterize, (0, None, None))))
    with pytest.raises(ValueError, match="cam.near: -1.0 must be > 0"):
        render(cams, V, F)


# ----------------------------------------------------------------------------------------------
# skinning
# ----------------------------------------------------------------------------------------------


LBS_ARGS = _lbs_args()  # 3 bones, 10 vertices, 2 influences (test_inputs' blend skinning)
lbs_checked = jaxgfx.checked(jax.jit(skin.linear_blend_skinning))
dqs_checked = jaxgfx.checked(jax.jit(skin.dual_quaternion_skinning))


def _lbs_with(i, value):
    return tuple(value if k == i else a for k, a in enumerate(LBS_ARGS))


SKIN_CASES = {
    "NaN transform": (_lbs_with(0, _nan_at(LBS_ARGS[0], (1, 0, 3))), "transforms: 1 of 36"),
    "joint out of range": (
        _lbs_with(3, np.where(np.arange(20).reshape(10, 2) == 5, 7, LBS_ARGS[3])),
        "joints: index 7 out of range for 3 bones",
    ),
    "NaN weight": (_lbs_with(4, _nan_at(LBS_ARGS[4], (2, 1))), "weights: 1 of 20 values"),
    "weights not summing to one": (
        _lbs_with(4, LBS_ARGS[4] * 3),
        "weights: a vertex's weights sum to 3.0",
    ),
    "NaN bind positions": (_lbs_with(1, _nan_at(LBS_ARGS[1], (0, 0))), "vertices: 1 of 30"),
}


@pytest.mark.parametrize("kernel", ["linear_blend_skinning", "dual_quaternion_skinning"])
@pytest.mark.parametrize("case", sorted(SKIN_CASES))
def test_checked_blend_skinning_names_a_bad_traced_value(kernel, case):
    args, message = SKIN_CASES[case]
    fn = lbs_checked if kernel == "linear_blend_skinning" else dqs_checked
    with pytest.raises(ValueError, match=f"{message}.*in {kernel}"):
        fn(*args)


def test_eager_calls_refuse_the_same_values_before_any_work():
    with pytest.raises(ValueError, match="weights: 1 of 20 values are NaN"):
        skin.linear_blend_skinning(*_lbs_with(4, _nan_at(LBS_ARGS[4], (2, 1))))
    with pytest.raises(ValueError, match="transforms: 1 of 36 values are NaN"):
        skin.dual_quaternion_skinning(*_lbs_with(0, _nan_at(LBS_ARGS[0], (1, 0, 3))))
    with pytest.raises(ValueError, match="camera rotation must be finite"):
        jaxgfx.background(_cam(rotation=[1.0, NAN, 0.0, 0.0]))  # a NaN sky otherwise


def test_checks_hold_under_grad_and_when_jit_is_outside():
    frame = jaxgfx.Frame(jnp.zeros((2, 3, 3)), jnp.arange(6.0).reshape(2, 3))

    def fogged(density):
        return jnp.sum(jaxgfx.fog(frame, density=density).color)

    grad = jaxgfx.checked(jax.jit(jax.grad(fogged)))
    assert float(grad(0.3)) == pytest.approx(float(jax.grad(fogged)(0.3)), rel=1e-5)
    with pytest.raises(ValueError, match=r"density: -1.0 must be >= 0 \(in fog\)"):
        grad(-1.0)

    def loss(t):
        pos, _ = skin.linear_blend_skinning(t, *LBS_ARGS[1:])
        return jnp.sum(pos)

    # jit outside: a host callback raises while the program runs
    outside = jax.jit(jaxgfx.checked(loss))
    assert np.isfinite(float(outside(LBS_ARGS[0])))
    with pytest.raises(jax.errors.JaxRuntimeError, match="transforms: 1 of 36 values are NaN"):
        jax.block_until_ready(outside(_nan_at(LBS_ARGS[0], (0, 0, 0))))


def test_checked_spline_skinning_names_a_bad_traced_value():
    # One straight spline and four vertices bound to it by hand (bind_mesh would compile).
    rig = skin.make_rig([[[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]])
    pose = rig.bind
    n = 4
    local = np.tile(np.array([[[0.2, 0.0, 0.0]]], np.float32), (n, 1, 1))
    binding = skin.SkinBinding(
        spline=np.zeros((n, 1), np.int32),
        weight=np.ones((n, 1), np.float32),
        x=np.linspace(0.1, 0.9, n, dtype=np.float32)[:, None],
        local=local,
        local_normal=local * 5,
        rest=local[:, 0] + np.array([0.0, 0.0, 1.0], np.float32),
        rest_normal=local[:, 0] * 5,
    )
    sampled = skin.prepare_sampled(binding)

    def both(pose, binding, sampled):
        # exact and sampled spline skinning in one program: the first failed check names
        # the kernel that found it
        return (
            skin.skin_exact(rig, pose, binding),
            skin.skin_sampled(rig, pose, sampled),
        )

    run = jaxgfx.checked(jax.jit(both))
    run(pose, binding, sampled)
    nan_points = dataclasses.replace(pose, points=pose.points.at[0, 1, 2].set(jnp.nan))
    with pytest.raises(ValueError, match=r"pose.points: 1 of 9 values .*\(in skin_exact\)"):
        run(nan_points, binding, sampled)
    soft = dataclasses.replace(pose, stiffness=pose.stiffness.at[0].set(1.5))
    with pytest.raises(ValueError, match=r"pose.stiffness: 1.5 must be finite and >= 2"):
        run(soft, binding, sampled)
    spline = binding.spline.copy()
    spline[2, 0] = 3
    with pytest.raises(ValueError, match="binding.spline: index 3 out of range for 1 splines"):
        run(pose, binding._replace(spline=spline), sampled)
    coord = np.array(sampled.coord)
    coord[2, 0] = -1.0
    with pytest.raises(ValueError, match=r"binding.coord: -1.0 is outside the table's rows"):
        run(pose, binding, sampled._replace(coord=coord))


# ----------------------------------------------------------------------------------------------
# silhouettes and the ray caster
# ----------------------------------------------------------------------------------------------


def test_checked_analytic_antialias_names_a_bad_traced_value(raster_jit):
    edges = silhouette_edges(F)
    out = raster_jit(CAM, V, F, V)  # the program test_good_input_... compiled
    run = jaxgfx.checked(
        jax.jit(lambda cam, v, o: analytic_antialias(cam, v, F, o, edges=edges, background=0.0))
    )
    run(CAM, V, out)
    with pytest.raises(ValueError, match=r"cam.far: .* \(in analytic_antialias\)"):
        run(_cam(far=0.01), V, out)
    with pytest.raises(ValueError, match="raster_out.tri_id: index 80 out of range for 80"):
        run(CAM, V, out._replace(tri_id=out.tri_id.at[3, 4].set(80)))
    with pytest.raises(ValueError, match="color: 1 of 576 values"):
        run(CAM, V, out._replace(color=out.color.at[0, 0, 0].set(jnp.nan)))


def test_checked_render_rle_names_a_bad_traced_camera(monkeypatch):
    from jaxgfx._src.voxel import render

    # The checks run before the ray caster's kernel, which is replaced by an empty frame:
    # compiling the real one would take most of a minute here, and test_raycast covers it.
    def empty_frame(settings):
        def frame(rle, cam, lod):
            h, w = cam.height, cam.width
            return render.RenderOutput(jnp.zeros((h, w, 3)), jnp.full((h, w), jnp.inf), {})

        return frame

    monkeypatch.setattr(render, "_frame_kernel", empty_frame)
    rle = raycast.as_jax(raycast.encode_rle(raycast.procedural_tree(8, key=jax.random.key(0))))
    cam = look_at([20.0, 10.0, -15.0], [4.0, 4.0, 4.0], 50.0, 16, 12, 0.5, 100.0)
    run = jaxgfx.checked(jax.jit(raycast.render_rle))
    run(rle, cam)
    bad = dataclasses.replace(cam, position=jnp.array([20.0, jnp.inf, -15.0]))
    with pytest.raises(ValueError, match=r"cam.position: 1 of 3 values .*\(in render_rle\)"):
        run(rle, bad)
    with pytest.raises(ValueError, match=r"lod_distance: nan must be > 0"):
        run(rle, cam, lod_distance=jnp.float32(jnp.nan))
    # eagerly the same lod_distance is refused before tracing
    with pytest.raises(ValueError, match="lod_distance"):
        raycast.render_rle(rle, cam, lod_distance=float("nan"))


# ----------------------------------------------------------------------------------------------
# the camera's size
# ----------------------------------------------------------------------------------------------


def test_a_camera_of_too_many_pixels_is_refused_naming_its_size():
    with pytest.raises(ValueError, match=r"width x height = 100000 x 100000 .* 2147483647"):
        look_at([0, 0, 3], [0, 0, 0], 50.0, 100000, 100000)
    huge = Camera(
        position=[0, 0, 3], rotation=[0, 0, 0, 1], focal=[9e4, 9e4], principal=[5e4, 5e4],
        near=0.1, far=10.0, width=100000, height=100000,
    )  # fmt: skip
    with pytest.raises(ValueError, match="width x height"):
        rasterize(huge, V, F)
    # the largest frame the int32 pixel indices allow passes the check
    look_at([0, 0, 3], [0, 0, 0], 50.0, 46340, 46340)
