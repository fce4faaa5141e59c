"""Library functions refuse bad input with a TypeError/ValueError that names the argument,
inside ``jit`` as well as eagerly; cameras from lists and 64-bit inputs work."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxgfx import raycast, skin, terrain
from jaxgfx.camera import Camera, look_at
from jaxgfx.raster import rasterize
from jaxgfx.silhouette import analytic_antialias

SPHERE = trimesh.creation.icosphere(subdivisions=1)
V = np.asarray(SPHERE.vertices, np.float32)
F = np.asarray(SPHERE.faces, np.int32)
CAM = look_at([0.4, 0.3, 3.0], [0, 0, 0], 50.0, 16, 12, 0.1, 9.0)


@pytest.fixture(scope="module")
def rle():
    return raycast.as_jax(raycast.encode_rle(raycast.procedural_tree(16, key=jax.random.key(0))))


def _lbs_args():
    rng = np.random.default_rng(0)
    t = np.tile(np.eye(3, 4, dtype=np.float32), (3, 1, 1))
    j = rng.integers(0, 3, (10, 2)).astype(np.int32)
    w = np.full((10, 2), 0.5, np.float32)
    p = rng.normal(size=(10, 3)).astype(np.float32)
    return t, p, p, j, w


def _with(tup, i, value):
    return tuple(value if k == i else x for k, x in enumerate(tup))


BAD = {
    # rasterize: shapes and dtypes are checked on abstract values, so also under jit
    "vertices (V, 2) under jit": (
        lambda: jax.jit(lambda v: rasterize(CAM, v, F).depth)(V[:, :2]),
        ValueError,
        "vertices",
    ),
    "integer vertices": (lambda: rasterize(CAM, F, F), TypeError, "vertices"),
    "float faces under jit": (
        lambda: jax.jit(lambda f: rasterize(CAM, V, f).depth)(F.astype(np.float32)),
        TypeError,
        "faces",
    ),
    "faces (F, 4)": (lambda: rasterize(CAM, V, np.zeros((3, 4), np.int32)), ValueError, "faces"),
    "faces out of range": (lambda: rasterize(CAM, V, F + len(V)), ValueError, "faces"),
    "attributes of other length under jit": (
        lambda: jax.jit(lambda a: rasterize(CAM, V, F, a).color)(V[:5]),
        ValueError,
        "attributes",
    ),
    "NaN vertices": (lambda: rasterize(CAM, V * np.nan, F), ValueError, "vertices"),
    "block 0": (lambda: rasterize(CAM, V, F, block=0), ValueError, "block"),
    "chunk a string": (lambda: rasterize(CAM, V, F, chunk="64"), TypeError, "chunk"),
    "cull_backfaces a string": (
        lambda: rasterize(CAM, V, F, cull_backfaces="yes"),
        TypeError,
        "cull_backfaces",
    ),
    "batching unknown": (lambda: rasterize(CAM, V, F, batching="loop"), ValueError, "batching"),
    "camera not a Camera": (lambda: rasterize({"position": 0}, V, F), TypeError, "cam"),
    # cameras
    "camera position (2,) under jit": (
        lambda: jax.jit(lambda c: rasterize(c, V, F).depth)(
            dataclasses.replace(CAM, position=jnp.zeros(2))
        ),
        ValueError,
        "position",
    ),
    "camera focal 0": (
        lambda: rasterize(dataclasses.replace(CAM, focal=[0.0, 0.0]), V, F),
        ValueError,
        "focal",
    ),  # fmt: skip
    "camera string rotation": (
        lambda: rasterize(dataclasses.replace(CAM, rotation="0"), V, F),
        TypeError,
        "rotation",
    ),  # fmt: skip
    "camera far <= near": (
        lambda: rasterize(dataclasses.replace(CAM, far=0.05), V, F),
        ValueError,
        "far",
    ),
    # the ray caster
    "render_rle NaN camera": (
        lambda rle: raycast.render_rle(
            rle, dataclasses.replace(CAM, position=jnp.full(3, jnp.nan))
        ),
        ValueError,
        "position",
    ),
    "render_rle camera too large": (
        lambda rle: raycast.render_rle(rle, dataclasses.replace(CAM, width=40000)),
        ValueError,
        "camera size",
    ),
    "render_rle dense array": (
        lambda rle: raycast.render_rle(np.zeros((4, 4, 4)), CAM),
        TypeError,
        "rle",
    ),
    "render_rle settings dict": (
        lambda rle: raycast.render_rle(rle, CAM, settings={"oversample": 1.0}),
        TypeError,
        "settings",
    ),
    "RenderSettings oversample 0": (
        lambda: raycast.RenderSettings(oversample=0.0),
        ValueError,
        "oversample",
    ),
    "RenderSettings neighbors -1": (
        lambda: raycast.RenderSettings(neighbors=-1),
        ValueError,
        "neighbors",
    ),
    "RenderSettings refine_steps -1": (
        lambda: raycast.RenderSettings(refine_steps=-1),
        ValueError,
        "refine_steps",
    ),
    # skinning
    "LBS joints out of range": (
        lambda: skin.linear_blend_skinning(*_with(_lbs_args(), 3, _lbs_args()[3] + 3)),
        ValueError,
        "joints",
    ),
    "LBS weights not summing to one": (
        lambda: skin.linear_blend_skinning(*_with(_lbs_args(), 4, _lbs_args()[4] * 3)),
        ValueError,
        "weights",
    ),
    "DQS transforms (J, 3, 3)": (
        lambda: skin.dual_quaternion_skinning(*_with(_lbs_args(), 0, np.zeros((3, 3, 3)))),
        ValueError,
        "transforms",
    ),
    # silhouettes and terrain
    "antialias colour of another size": (
        lambda: analytic_antialias(CAM, V, F, rasterize(CAM, V, F), jnp.zeros((5, 5, 3))),
        ValueError,
        "color",
    ),
    "a terrain that is no terrain": (lambda: terrain.check_terrain("saw"), TypeError, "terrain"),
    "a viewer of 2 coordinates": (
        lambda: terrain.check_viewer(terrain.SawTerrain(), (0, 5)),
        ValueError,
        "viewer",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_names_the_argument(case, rle):
    fn, error, name = BAD[case]
    with pytest.raises(error, match=name):
        fn(rle) if fn.__code__.co_argcount else fn()


def test_camera_from_lists_is_one_leaf_per_field():
    cam = Camera(position=[0, 0, -3], rotation=[0, 0, 0, 1], focal=[11.0, 11.0],
                 principal=[8, 6], near=0.1, far=10.0, width=16, height=12)  # fmt: skip
    assert len(jax.tree_util.tree_leaves(cam)) == 6
    assert np.asarray(cam.position).dtype == np.float32
    out = jax.jit(rasterize)(cam, V, F)
    assert np.isfinite(np.asarray(out.depth)).any()


def test_kernels_under_x64_equal_the_32_bit_results(rle):
    # rasterize and render_rle compute in 32 bits whatever the inputs; skinning and terrain
    # sampling run in the caller's precision.
    rng = np.random.default_rng(1)
    t, p, n, j, w = _lbs_args()
    t = t + rng.normal(size=t.shape).astype(np.float32) * 0.1
    rcam = look_at([40.0, 20.0, -30.0], [8.0, 8.0, 8.0], 50.0, 16, 12, 0.5, 200.0)
    ref = (  # jitted: an eager call compiles its loops op by op, at every call
        jax.jit(rasterize)(CAM, V, F),
        jax.jit(raycast.render_rle)(rle, rcam),
        skin.linear_blend_skinning(t, p, n, j, w),
        skin.dual_quaternion_skinning(t, p, n, j, w),
        terrain.sample_terrain(
            terrain.SawTerrain(), jnp.zeros(3, jnp.int32), level=1, shape=(6, 6, 6)
        ),  # fmt: skip
    )
    with jax.enable_x64(True):
        cam64 = jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64), CAM)
        rcam64 = jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64), rcam)
        f64 = [np.asarray(x, np.float64) for x in (t, p, n)]
        out = (
            jax.jit(rasterize)(cam64, V.astype(np.float64), F.astype(np.int64)),
            jax.jit(raycast.render_rle)(rle, rcam64),
            skin.linear_blend_skinning(*f64, j.astype(np.int64), w.astype(np.float64)),
            skin.dual_quaternion_skinning(*f64, j.astype(np.int64), w.astype(np.float64)),
            terrain.sample_terrain(
                terrain.SawTerrain(), np.zeros(3, np.int64), level=1, shape=(6, 6, 6)
            ),  # fmt: skip
        )
        assert out[0].depth.dtype == jnp.float32 and out[1].depth.dtype == jnp.float32
        assert out[2][0].dtype == jnp.float64
    for a, b in zip(jax.tree_util.tree_leaves(ref), jax.tree_util.tree_leaves(out), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype.kind in "iub":
            np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)
