"""Tests for jaxgfx.terrain (thesis chapter 3): terrain functions, Clip-Boxes, meshes, seams."""

from __future__ import annotations

import copy
import dataclasses
import json
import os
import time
import warnings
from collections import Counter

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgfx import terrain as T
from jaxgfx._src.terrain.functions import _sample_points

DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "terrain")
N = 16
ROUND = 3  # welded positions are compared after rounding to 1e-3 voxel units

sample_jit = jax.jit(T.sample_terrain, static_argnames=("shape",))
# One pipeline's jitted steps serve every test, so each step compiles once.
PIPE = T.ClipBoxPipeline(
    T.SawTerrain(modulus=40, threshold=20), size=N, levels=3, max_quads=6000, smoothing=3
)
clipbox_jit = PIPE.sample_fn
shift_jit = PIPE.shift_fn


def mesh_jit(box, max_quads=6000, seam=True):
    return PIPE.extract_fn(box, max_quads=max_quads, seam=seam)


def smooth_jit(box):
    return PIPE.normals_fn(PIPE.smooth_fn(mesh_jit(box), iterations=3))


weld_jit = PIPE.weld_fn
vis_jit = jax.jit(T.visible_faces)


def grid_points(origin, shape, step=1):
    idx = [np.arange(n, dtype=np.int64) * step for n in shape]
    g = np.stack(np.meshgrid(*idx, indexing="ij"), -1) + np.asarray(origin, np.int64)
    return g


def sample_np(fn_np, origin, shape, step=1):
    g = grid_points(origin, shape, step)
    return fn_np(g[..., 0], g[..., 1], g[..., 2])


def sample(t, origin, shape, level=0):
    return np.asarray(sample_jit(t, jnp.asarray(origin, jnp.int32), level=level, shape=shape))


# ---------------------------------------------------------------- Eq. 3.2, exact integers

ORIGINS = [
    (0, 0, 0),
    (-517, 33, -2001),
    (1_000_000_000, -7, 999_999_000),
    (2**31 - 40, -(2**31), 5),
]


@pytest.mark.parametrize("origin", ORIGINS)
def test_xor_saw_sin_match_numpy(origin):
    shape = (20, 12, 16)
    xor_np = lambda x, y, z: np.mod(x ^ y ^ z, 1000) < 357  # noqa: E731
    saw_np = lambda x, y, z: np.mod(x + y + z, 1000) < 500  # noqa: E731
    sin_np = lambda x, y, z: np.sin(x) + np.sin(y) + np.sin(z) < 2  # noqa: E731
    np.testing.assert_array_equal(
        sample(T.XorTerrain(), origin, shape), sample_np(xor_np, origin, shape)
    )
    np.testing.assert_array_equal(
        sample(T.SawTerrain(), origin, shape), sample_np(saw_np, origin, shape)
    )
    np.testing.assert_array_equal(
        sample(T.SinTerrain(), origin, shape), sample_np(sin_np, origin, shape)
    )
    # A narrower modulus/threshold exercises many more sign changes.
    saw7 = T.SawTerrain(modulus=7, threshold=3)
    np.testing.assert_array_equal(
        sample(saw7, origin, shape),
        sample_np(lambda x, y, z: np.mod(x + y + z, 7) < 3, origin, shape),
    )


def test_int_sin_accuracy_everywhere():
    x = np.concatenate(
        [np.arange(-3000, 3000), np.random.default_rng(0).integers(-(2**31), 2**31 - 1, 20000)]
    ).astype(np.int64)
    got = np.asarray(jax.jit(T.int_sin)(jnp.asarray(x, jnp.int32)))
    np.testing.assert_allclose(got, np.sin(x.astype(np.float64)), atol=1e-6, rtol=0)


# ---------------------------------------------------------------- CSG with bins


def csg_reference(csg: T.CSGTerrain, pts: np.ndarray) -> np.ndarray:
    """Sequential Boolean operations, O(points x primitives), no bins."""
    c = np.asarray(csg.centers, np.int64)
    e = np.asarray(csg.extents, np.int64)
    k = np.asarray(csg.kinds)
    u = np.asarray(csg.union)
    per, half = csg.period, csg.period // 2
    out = pts[..., 1] < csg.ground
    for i in range(c.shape[0]):
        dx = np.mod(pts[..., 0] - c[i, 0] + half, per) - half
        dz = np.mod(pts[..., 2] - c[i, 2] + half, per) - half
        dy = pts[..., 1] - c[i, 1]
        if k[i] == T.PRIMITIVE_SPHERE:
            inside = dx**2 + dy**2 + dz**2 <= e[i, 0] ** 2
        elif k[i] == T.PRIMITIVE_BOX:
            inside = (np.abs(dx) <= e[i, 0]) & (np.abs(dy) <= e[i, 1]) & (np.abs(dz) <= e[i, 2])
        else:
            inside = (dx**2 + dz**2 <= e[i, 0] ** 2) & (np.abs(dy) <= e[i, 1])
        out = np.where(inside, u[i], out)
    return out


def small_csg_terrain(seed: int) -> T.CSGTerrain:
    return T.random_csg_terrain(
        key=jax.random.PRNGKey(seed),
        count=120,
        period=64,
        y_range=(-24, 24),
        radius=(2, 7),
        bin_size=8,
    )


@pytest.fixture(scope="module")
def small_csg():
    return small_csg_terrain(3)


@pytest.mark.parametrize("origin", [(-40, -30, -40), (1_000_000_000, -20, -1_000_000_000)])
def test_csg_matches_bruteforce(small_csg, origin):
    shape = (72, 52, 20)  # crosses the tiling period and the y range of the bins
    got = sample(small_csg, origin, shape)
    want = csg_reference(small_csg, grid_points(origin, shape))
    np.testing.assert_array_equal(got, want)
    assert 0 < got.mean() < 1
    # Binning: a point tests at most K primitives, far fewer than all of them.
    assert small_csg.bins.shape[1] < small_csg.centers.shape[0] // 4


grid_jit = jax.jit(T.sample_terrain, static_argnames=("level", "shape"))


@pytest.mark.parametrize("level", [0, 1, 2, 3])
def test_csg_grid_path_matches_bruteforce(small_csg, level):
    # A static level takes CSGTerrain.sample_grid: shared bins (2^level < bin_size) or
    # the y band point by point; unaligned origins, the period and the y range crossed.
    step = 1 << level
    for origin in [(-37, -29, 13), (1_000_000_003, -21 + step, -999_999_995)]:
        shape = (24, 40 // step + 3, 9)
        got = np.asarray(
            grid_jit(small_csg, jnp.asarray(origin, jnp.int32), level=level, shape=shape)
        )
        want = csg_reference(small_csg, grid_points(origin, shape, step))
        np.testing.assert_array_equal(got, want)
    both = T.Difference(T.Union(small_csg, T.SawTerrain(modulus=9, threshold=2)), small_csg)
    o = jnp.asarray((5, -10, 7), jnp.int32)
    fast = grid_jit(both, o, level=level, shape=(8, 8, 8))
    np.testing.assert_array_equal(fast, sample(both, o, (8, 8, 8), level=level))


def test_csg_same_key_same_terrain(small_csg):
    again = small_csg_terrain(3)
    other = small_csg_terrain(4)
    for a, b in zip(jax.tree_util.tree_leaves(small_csg), jax.tree_util.tree_leaves(again)):
        np.testing.assert_array_equal(a, b)
    s = sample(small_csg, (0, -8, 0), (32, 16, 32))
    assert np.array_equal(s, sample(again, (0, -8, 0), (32, 16, 32)))
    assert not np.array_equal(s, sample(other, (0, -8, 0), (32, 16, 32)))


def test_csg_bad_input():
    with pytest.raises(ValueError, match="period"):
        T.csg_terrain(
            [[0, 0, 0]], [[2, 2, 2]], [0], [True], period=60, y_range=(-8, 8), bin_size=16
        )
    with pytest.raises(ValueError, match="y_range"):
        T.csg_terrain(
            [[0, 0, 0]], [[9, 9, 9]], [0], [True], period=64, y_range=(-8, 8), bin_size=16
        )
    with pytest.raises(ValueError, match="radius"):
        T.random_csg_terrain(key=jax.random.PRNGKey(0), radius=(5, 2))


# ---------------------------------------------------------------- height maps, volumes, combinators


def heightfield_np(h, m, x, z, apron=False):
    """NumPy float64 reference of the bilinear surface H(x, z): wrapped, clamped, or with
    ``apron`` the clamped edge fading to the apron's level (the module docstring's rule)."""
    rows, cols = h.shape
    rel = (np.asarray(h, np.float64) - h.min()) * m.vertical_scale
    cx, cz = m.cells
    u = (np.asarray(x, np.float64) - m.origin[0]) / cx - 0.5
    v = (np.asarray(z, np.float64) - m.origin[1]) / cz - 0.5
    if apron and not m.wrap:
        ex = np.maximum(np.maximum(-0.5 - u, u - (cols - 0.5)), 0) * cx
        ez = np.maximum(np.maximum(-0.5 - v, v - (rows - 0.5)), 0) * cz
        t = np.clip(np.hypot(ex, ez) / m.apron_fade, 0, 1)
        w = t * t * (3 - 2 * t)
        inner = heightfield_np(h, m, x, z)
        return inner * (1 - w) + (m.base + m.apron_height) * w
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = u - u0, v - v0
    c0, r0 = u0.astype(np.int64), v0.astype(np.int64)
    if m.wrap:
        c0, c1, r0, r1 = c0 % cols, (c0 + 1) % cols, r0 % rows, (r0 + 1) % rows
    else:
        c0, c1 = np.clip(c0, 0, cols - 1), np.clip(c0 + 1, 0, cols - 1)
        r0, r1 = np.clip(r0, 0, rows - 1), np.clip(r0 + 1, 0, rows - 1)
    top = rel[r0, c0] * (1 - fu) + rel[r0, c1] * fu
    bottom = rel[r1, c0] * (1 - fu) + rel[r1, c1] * fu
    return m.base + top * (1 - fv) + bottom * fv


HEIGHT_TOL = 1e-3  # voxels: float32 surface vs the float64 reference


@pytest.mark.parametrize(
    "kw",
    [
        dict(vertical_scale=2.0, cell=2.5, origin=(-3.25, 4.0), base=-2.5),
        dict(vertical_scale=1.5, cell=2, base=3, wrap=True),
    ],
)
def test_heightmap_terrain_matches_numpy(kw):
    h = np.random.default_rng(3).random((4, 5)) * 6
    t = T.heightmap_terrain(h, **kw)
    m = t.mapping
    origin, shape = (-14, -6, -9), (24, 20, 22)
    for level in (0, 1):
        g = grid_points(origin, shape, 1 << level)
        surf = heightfield_np(h, m, g[..., 0] + 0.5, g[..., 2] + 0.5, apron=True)
        want = g[..., 1] + 0.5 < surf
        got = sample(t, origin, shape, level)
        unsure = np.abs(g[..., 1] + 0.5 - surf) < HEIGHT_TOL
        np.testing.assert_array_equal(got[~unsure], want[~unsure])
        # the per-column fast path equals vmap of the point function
        pts = _sample_points(t, jnp.asarray(origin, jnp.int32), level, shape)
        np.testing.assert_array_equal(got, np.asarray(pts))
    assert got.any() and not got.all()


def test_heightmap_mapping_formulas_and_json():
    h = np.array([[3.0, 5.0, 4.0], [7.0, 3.5, 9.0]])
    t = T.heightmap_terrain(h, cell=4, vertical_scale=0.5, base=10)
    m = t.mapping
    # centred on the world origin, rounded to whole voxels
    assert m.origin == (-6.0, -4.0) and m.shape == (2, 3) and m.min_value == 3.0
    assert not m.wrap and hash(m) == hash(dataclasses.replace(m))
    d = m.to_dict()
    keys = {"origin", "cell", "vertical_scale", "base", "shape", "edge", "apron", "crs"}
    assert set(d) == keys | {"metres_per_sample", "metres_per_voxel", "nodata"}
    assert d["cell"] == [4.0, 4.0] and d["edge"] == "apron" and d["metres_per_voxel"] is None
    assert d["nodata"] == {"count": 0, "fraction": 0.0}  # an array: no voids
    assert T.heightmap_terrain(h, wrap=True).mapping.to_dict()["edge"] == "wrap"
    assert json.loads(json.dumps(d)) == d
    r, c = np.meshgrid(np.arange(2), np.arange(3), indexing="ij")
    pos = m.sample_position(r, c, h)
    np.testing.assert_allclose(pos[..., 0], -6 + (c + 0.5) * 4)
    np.testing.assert_allclose(pos[..., 2], -4 + (r + 0.5) * 4)
    np.testing.assert_allclose(pos[..., 1], 10 + (h - 3) * 0.5)
    # the surface passes through every sample
    g = np.asarray(T.ground_height(t, pos[..., 0], pos[..., 2]))
    np.testing.assert_allclose(g, pos[..., 1], atol=HEIGHT_TOL)
    for bad, match in [
        (dict(cell=0), "cell"),
        (dict(vertical_scale=-1), "vertical_scale"),
        (dict(origin=(1, 2, 3)), "origin"),
        (dict(cell=1.5, wrap=True), "cell"),
        (dict(base=float("nan")), "base"),
    ]:
        with pytest.raises(ValueError, match=match):
            T.heightmap_terrain(h, **bad)
    with pytest.raises(TypeError, match="wrap"):
        T.heightmap_terrain(h, wrap=1)
    with pytest.raises(TypeError, match="terrain"):
        T.ground_height(T.SawTerrain(), 0.0, 0.0)


def test_heightmap_edges_apron_or_wrapped():
    h = np.random.default_rng(4).random((3, 4)) * 8
    clamp = T.heightmap_terrain(h, cell=2, vertical_scale=1.0, apron_fade=20.0)
    wrap = T.heightmap_terrain(h, cell=2, vertical_scale=1.0, wrap=True)
    m = clamp.mapping
    far = np.array([-40.0, -9.0, 30.0, 57.0])
    zc = np.full(4, m.origin[1] + 0.5 * m.cell)  # row 0's sample centres
    # apron: beyond the map the edge samples extend outwards, fading to the apron's level
    g = np.asarray(T.ground_height(clamp, far, zc))
    np.testing.assert_allclose(g[[0, -1]], m.apron_height, atol=HEIGHT_TOL)
    dist = np.maximum(np.maximum(m.origin[0] - far, far - (m.origin[0] + 8)), 0.0)
    w = np.clip(dist / 20.0, 0, 1)
    w = w * w * (3 - 2 * w)
    want = heightfield_np(h, m, far, zc) * (1 - w) + m.apron_height * w
    np.testing.assert_allclose(g, want, atol=HEIGHT_TOL)
    # wrapped: periodic with period (cols cell, rows cell), also exactly at 10^9
    period = (4 * 2, 3 * 2)
    gw = np.asarray(T.ground_height(wrap, far, zc))
    np.testing.assert_allclose(
        gw, np.asarray(T.ground_height(wrap, far + period[0], zc)), atol=1e-4
    )
    np.testing.assert_allclose(gw, heightfield_np(h, wrap.mapping, far, zc), atol=HEIGHT_TOL)
    a = sample(wrap, (-8, -2, -6), (8, 12, 6))
    b = sample(wrap, (-8 + 125_000_000 * period[0], -2, -6 + 10**8 * period[1]), (8, 12, 6))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(sample(clamp, (-40, -2, -6), (8, 12, 6)), a)


def test_heightmap_has_no_terraces_at_fine_levels():
    # two samples 4 voxels apart: the ground between them rises voxel by voxel
    t = T.heightmap_terrain(np.array([[0.0, 8.0]]), cell=4, vertical_scale=1.0)
    vox = sample(t, (-4, -2, -2), (8, 14, 4))[:, :, 0]  # (x, y) of one z row
    tops = vox.sum(axis=1)  # solid voxels per column from y = -2
    assert np.all(np.diff(tops) >= 0) and np.all(np.diff(tops[2:6]) > 0)
    assert len(set(tops.tolist())) >= 5


def test_ground_height_matches_voxel_tops():
    h = np.random.default_rng(5).random((6, 7)) * 20
    t = T.heightmap_terrain(h, cell=3, vertical_scale=0.8, base=-7)
    xs, zs = np.meshgrid(np.arange(-14, 14, 3), np.arange(-12, 12, 3), indexing="ij")
    g = np.asarray(jax.jit(jax.vmap(T.ground_height, (None, 0, 0)))(t, xs + 0.5, zs + 0.5))
    vox = sample(t, (-14, -10, -12), (28, 32, 24))[::3, :, ::3]
    top = -10 + vox.shape[1] - np.argmax(vox[:, ::-1, :], axis=1)  # first air y
    assert vox[:, 0].all() and not vox[:, -1].any()
    assert np.abs(top - np.ceil(g - 0.5)).max() <= 1
    assert np.mean(top == np.ceil(g - 0.5)) > 0.95


def test_default_viewer_and_check_viewer():
    h = np.random.default_rng(6).random((8, 8)) * 10
    t = T.heightmap_terrain(h, cell=2, origin=(100, -50))
    x, y, z = T.default_viewer(t, height=5)
    assert (x, z) == (108, -42)
    g = float(T.ground_height(t, x + 0.5, z + 0.5))
    assert y == int(np.ceil(g - 0.5)) + 5
    assert T.check_viewer(t, (x, y, z)) == (x, y, z)
    assert T.check_viewer(t, T.default_viewer(t)) is not None
    with pytest.raises(ValueError, match="viewer .* inside solid ground"):
        T.check_viewer(t, (x, y - 6, z))
    with pytest.raises(ValueError, match="camera"):
        T.check_viewer(T.SawTerrain(), (0, -(2**31), 0), name="camera")
    with pytest.raises(ValueError, match="viewer"):
        T.check_viewer(t, (0.5, 1, 2))


def test_terrain_colors_by_slope_and_height():
    flat, steep = [0.0, 1.0, 0.0], [0.8, 0.2, 0.0]
    steep = list(np.asarray(steep) / np.linalg.norm(steep))
    v = np.array([[3.0, 2.0, 5.0], [3.0, 98.0, 5.0], [40.0, 50.0, -7.0], [3.0, 98.001, 5.0]])
    n = np.array([flat, flat, steep, flat])
    c = np.asarray(T.terrain_colors(v, n, height_range=(0.0, 100.0)))
    assert c.shape == (4, 3) and c.dtype == np.float32 and np.all((c >= 0) & (c <= 1))
    grass, snow, rock = c[0], c[1], c[2]
    assert grass[1] > grass[0] and grass[1] > grass[2]  # green
    assert snow.min() > 0.7 and np.ptp(snow) < 0.15  # white
    assert rock[0] >= rock[1] and np.ptp(rock) < 0.3  # grey-brown, not green
    np.testing.assert_allclose(c[3], c[1], atol=1e-3)  # continuous: no seams between levels
    bare = np.asarray(T.terrain_colors(v, n, height_range=(0.0, 100.0), snow_line=None))
    assert bare[1].min() < 0.7
    with pytest.raises(ValueError, match="height_range"):
        T.terrain_colors(v, n, height_range=(5.0, 5.0))
    with pytest.raises(ValueError, match="normals"):
        T.terrain_colors(v, n[:2], height_range=(0.0, 1.0))


def test_terrain_colors_exact_far_from_the_origin():
    # The detail field and strata come from the integer world position (whole cycles per
    # DETAIL_PERIOD): vertices relative to an origin 10^9 away get the same colours, bit
    # for bit, as the same vertices relative to the world origin.
    rng = np.random.default_rng(8)
    v = rng.uniform(-200, 200, (256, 3)).astype(np.float32)
    n = rng.normal(size=(256, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    colors = jax.jit(T.terrain_colors, static_argnames=("height_range",))
    kw = dict(height_range=(-50.0, 150.0))
    near = np.asarray(colors(v, n, origin=jnp.asarray([120, 40, -7], jnp.int32), **kw))
    far = np.asarray(
        colors(v, n, origin=jnp.asarray([120 + 10**9, 40, -7 - 10**9], jnp.int32), **kw)
    )
    np.testing.assert_array_equal(near, far)
    # the field does vary along x (not a constant), and world = origin + vertex
    shifted = np.asarray(colors(v, n, origin=jnp.asarray([120 + 37, 40, -7], jnp.int32), **kw))
    assert np.abs(shifted - near).max() > 0.01
    world = np.asarray(colors(v + np.float32([120, 40, -7]), n, **kw))
    np.testing.assert_allclose(world, near, atol=2e-3)


def test_dem_fill_grows_known_samples_outwards():
    from jaxgfx._src.terrain.elevation import _fill_outside

    nan = np.nan
    g = np.array([[nan, nan, 4.0], [nan, 2.0, 6.0], [nan, nan, nan]])
    f = _fill_outside(g)
    # ring by ring: each cell the mean of its known 4-neighbours when it is reached
    want = np.array([[2.5, 3.0, 4.0], [2.0, 2.0, 6.0], [2.0, 2.0, 6.0]])
    np.testing.assert_array_equal(f, want)
    assert np.isnan(g).sum() == 6  # the input is not changed


@pytest.mark.skipif(not os.path.isdir(DATA), reason="../shared/data/terrain is absent")
def test_st_helens_true_proportions():
    with warnings.catch_warnings():
        warnings.simplefilter("error", T.NodataWarning)  # no voids: no warning
        d = T.read_heightmap(os.path.join(DATA, "SainteHelens.dem"))
    assert d.spacing == (30.0, 30.0) and d.height_unit == 1.0 and d.heights.shape == (466, 327)
    # the corners outside the quad are filled, but they are no voids
    assert d.filled == 3497 and d.nodata == 0 and d.nodata_value == -32767
    t = T.heightmap_terrain(os.path.join(DATA, "SainteHelens.dem"), cell=2)
    m = t.mapping
    assert m.vertical_scale == pytest.approx(2 / 30) and m.origin == (-327, -466)
    assert m.to_dict()["metres_per_voxel"] == [15.0, 15.0, 15.0]
    # the summit stands (2543 - 682) / 30 * 2 voxels above the base, where the file puts it
    r, c = np.unravel_index(np.argmax(d.heights), d.heights.shape)
    x, y, z = m.sample_position(r, c, d.heights[r, c])
    assert y == pytest.approx((2543 - 682) / 15)
    assert float(T.ground_height(t, x, z)) == pytest.approx(y, abs=HEIGHT_TOL)
    # The grid's corners outside the DEM's rotated quad grow from their neighbours: the
    # steepest step between neighbouring samples is the volcano's own (86 m), where a
    # fill with the lowest height made a ~500 m moat around the map.
    h = d.heights
    assert max(np.abs(np.diff(h, axis=0)).max(), np.abs(np.diff(h, axis=1)).max()) < 100
    img = T.read_heightmap(os.path.join(DATA, "gcanyon_elev_crop.bw.png"))
    assert img.spacing is None and img.height_unit is None
    relief = float(np.max(np.asarray(T.heightmap_terrain(img).heights)))
    assert relief == pytest.approx(T.IMAGE_RELIEF * 1200, rel=1e-6)


@pytest.mark.skipif(not os.path.isdir(DATA), reason="../shared/data/terrain is absent")
def test_real_heightmaps_load():
    dem = T.load_heightmap(os.path.join(DATA, "SainteHelens.dem"))
    assert dem.ndim == 2 and min(dem.shape) > 100
    assert abs(dem.min() - 682) < 1 and abs(dem.max() - 2543) < 1  # header min/max
    img = T.load_heightmap(os.path.join(DATA, "gcanyon_elev_crop.bw.png"))
    assert img.shape == (1200, 1200)
    t = T.heightmap_terrain(dem, vertical_scale=1 / 30.0)
    assert sample(t, (0, 0, 0), (8, 70, 8)).any()


def test_heightmap_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="heightmap path"):
        T.load_heightmap(tmp_path / "missing.png")
    with pytest.raises(ValueError, match="is a directory"):
        T.load_heightmap(tmp_path)
    bad = tmp_path / "not_an_image.png"
    bad.write_text("hello")
    with pytest.raises(ValueError, match="not_an_image.png' is not a readable image"):
        T.load_heightmap(bad)
    dem = tmp_path / "broken.dem"
    dem.write_bytes(b"x" * 1100)
    with pytest.raises(ValueError, match="DEM"):
        T.load_heightmap(dem)
    hgt = tmp_path / "N10E010.hgt"
    hgt.write_bytes(b"\0" * 7)
    with pytest.raises(ValueError, match="2 n\\^2"):
        T.load_heightmap(hgt)
    unnamed = tmp_path / "tile.hgt"
    unnamed.write_bytes(b"\0" * 8)
    with pytest.raises(ValueError, match="N46W123.hgt"):
        T.load_heightmap(unnamed)
    asc = tmp_path / "short.asc"
    asc.write_text("ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 10\n1 2 3 4\n")
    with pytest.raises(ValueError, match="needs 6 values, found 4"):
        T.load_heightmap(asc)
    rotated = tmp_path / "rotated.tif"
    _write_geotiff(rotated, np.zeros((4, 5), np.float32), geographic=False, rotate=True)
    with pytest.raises(ValueError, match="rotated"):
        T.load_heightmap(rotated)
    cm = tmp_path / "odd_unit.tif"
    _write_geotiff(cm, np.zeros((4, 5), np.float32), geographic=False, linear_unit=9033)
    with pytest.raises(ValueError, match="linear unit 9033"):
        T.load_heightmap(cm)


# ---------------------------------------------------------------- elevation files (GeoTIFF, ...)


def _ecef(lat_deg, lon_deg):
    """WGS 84 geodetic -> Earth-centred Cartesian metres (the test's own truth)."""
    a, e2 = 6378137.0, 6.69437999014e-3
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.array(
        [n * np.cos(lat) * np.cos(lon), n * np.cos(lat) * np.sin(lon), n * (1 - e2) * np.sin(lat)]
    )


def _ground_spacing(lat, lon, dlon, dlat):
    """(east-west, north-south) metres between neighbouring samples at (lat, lon): the
    straight-line distance between their Earth-centred positions."""
    p = _ecef(lat, lon)
    return (
        float(np.linalg.norm(_ecef(lat, lon + dlon) - p)),
        float(np.linalg.norm(_ecef(lat + dlat, lon) - p)),
    )


def _write_geotiff(
    path,
    arr,
    *,
    geographic,
    scale=(1 / 1200, 1 / 1200),
    tie=(-122.5, 46.5),
    epsg=None,
    nodata=None,
    linear_unit=None,
    rotate=False,
):
    """A GeoTIFF written with tifffile: pixel scale, tie point, GeoKeys, GDAL_NODATA."""
    import tifffile

    keys = [(1024, 0, 1, 2 if geographic else 1), (1025, 0, 1, 1)]
    if geographic:
        keys.append((2048, 0, 1, epsg or 4326))
    else:
        keys.append((3072, 0, 1, epsg or 32610))
        if linear_unit is not None:
            keys.append((3076, 0, 1, linear_unit))
    directory = [1, 1, 0, len(keys)] + [v for k in keys for v in k]
    tags = [(34735, "H", len(directory), directory, False)]
    if rotate:
        m = [0.8 * scale[0], 0.6, 0, tie[0], 0.6, -0.8 * scale[1], 0, tie[1]]
        tags.append((34264, "d", 16, m + [0, 0, 0, 0, 0, 0, 0, 1], False))
    else:
        tags.append((33550, "d", 3, (scale[0], scale[1], 0.0), False))
        tags.append((33922, "d", 6, (0.0, 0.0, 0.0, tie[0], tie[1], 0.0), False))
    if nodata is not None:
        tags.append((42113, "s", 0, str(nodata), False))
    tifffile.imwrite(path, arr, extratags=tags, compression="zlib")


def _hills(rows, cols, lo, hi, seed=0):
    """A smooth field of a few Gaussian hills between ``lo`` and ``hi``."""
    rng = np.random.default_rng(seed)
    z, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    h = np.zeros((rows, cols))
    for _ in range(4):
        cz, cx, r = rng.uniform(0, rows), rng.uniform(0, cols), rng.uniform(3, 8)
        h += rng.uniform(0.3, 1.0) * np.exp(-((x - cx) ** 2 + (z - cz) ** 2) / (2 * r * r))
    return lo + (hi - lo) * (h - h.min()) / np.ptp(h)


def _check_true_proportions(t, spacing_truth):
    """metres_per_sample within 1 % of the truth, metres_per_voxel equal on x, y, z."""
    d = t.mapping.to_dict()
    np.testing.assert_allclose(d["metres_per_sample"], spacing_truth, rtol=0.01)
    mpv = np.asarray(d["metres_per_voxel"])
    np.testing.assert_allclose(mpv, mpv[0], rtol=0.01)
    # the surface stands where the mapping says: sample (r, c) at its world position
    m = t.mapping
    r, c = np.meshgrid(np.arange(m.shape[0]), np.arange(m.shape[1]), indexing="ij")
    return m, r, c


def test_geotiff_geographic_srtm_style(tmp_path):
    # 3 arc-second int16 metres at 46.5 N (St Helens' latitude), with voids
    h = np.round(_hills(24, 20, 700, 2500)).astype(np.int16)
    h[5, 6] = h[0, 0] = -32768
    path = tmp_path / "srtm_like.tif"
    _write_geotiff(path, h, geographic=True, nodata=-32768)
    with pytest.warns(T.NodataWarning, match=r"srtm_like.tif': 2 of 480 samples \(0.417 %\)"):
        d = T.read_heightmap(path)
    assert d.crs == "EPSG:4326" and d.filled == d.nodata == 2 and d.height_unit == 1.0
    assert d.nodata_value == -32768
    assert d.heights.min() >= 700 and d.heights[5, 6] > 700  # filled from its neighbours
    lat = 46.5 - 12 / 1200  # the map's centre latitude
    truth = _ground_spacing(lat, -122.5, 1 / 1200, 1 / 1200)
    assert truth[0] < 0.7 * truth[1]  # a degree of longitude is shorter up north
    t = T.heightmap_terrain(d)
    m, r, c = _check_true_proportions(t, truth)
    assert m.cells[1] == pytest.approx(truth[1] / truth[0], rel=0.01)
    pos = m.sample_position(r, c, d.heights)
    g = np.asarray(T.ground_height(t, pos[..., 0], pos[..., 2]))
    np.testing.assert_allclose(g, pos[..., 1], atol=HEIGHT_TOL)
    # the relief in voxels is the relief in metres over metres per voxel
    mpv = m.metres_per_voxel
    assert float(np.max(np.asarray(t.heights))) == pytest.approx(np.ptp(d.heights) / mpv[1])


def test_geotiff_projected_utm_and_feet(tmp_path):
    h = _hills(20, 24, -4200.0, -1500.0, seed=1).astype(np.float32)  # sea floor
    path = tmp_path / "utm.tif"
    _write_geotiff(path, h, geographic=False, scale=(30.0, 30.0), tie=(560000.0, 5120000.0))
    d = T.read_heightmap(path)
    assert d.crs == "EPSG:32610" and d.spacing == (30.0, 30.0)
    t = T.heightmap_terrain(d, cell=2)
    _check_true_proportions(t, (30.0, 30.0))
    assert t.mapping.to_dict()["metres_per_voxel"] == [15.0, 15.0, 15.0]
    assert float(np.max(np.asarray(t.heights))) == pytest.approx(np.ptp(h) / 15.0, rel=1e-5)
    feet = tmp_path / "feet.tif"
    _write_geotiff(feet, h, geographic=False, scale=(100.0, 100.0), epsg=2927, linear_unit=9003)
    d = T.read_heightmap(feet)
    np.testing.assert_allclose(d.spacing, 100 * 1200 / 3937, rtol=1e-12)  # US survey feet
    plain = tmp_path / "plain.tif"
    import tifffile

    tifffile.imwrite(plain, h)  # no GeoTIFF tags: an image without units
    assert T.read_heightmap(plain).spacing is None


def test_srtm_hgt_tile(tmp_path):
    n = 121  # 30 arc-seconds over one degree, edges shared with the neighbours
    h = np.round(_hills(n, n, 100, 1900, seed=2)).astype(">i2")
    h[60, 60] = -32768
    path = tmp_path / "S34E151.hgt"
    h.tofile(path)
    with pytest.warns(T.NodataWarning, match=r"1 of 14641 samples .* NODATA \(-32768\)"):
        d = T.read_heightmap(path)
    assert d.filled == d.nodata == 1 and d.heights.shape == (n, n) and d.heights[60, 60] > 0
    truth = _ground_spacing(-33.5, 151.5, 1 / 120, 1 / 120)
    _check_true_proportions(T.heightmap_terrain(d), truth)


def test_esri_ascii_grid(tmp_path):
    h = _hills(20, 24, 300.0, 1300.0, seed=3)
    h[3, 4] = -9999
    rows = "\n".join(" ".join(f"{v:.2f}" for v in row) for row in h)
    head = "ncols 24\nnrows 20\nxllcorner 500000\nyllcorner 4000000\ncellsize 25\n"
    path = tmp_path / "grid.asc"
    path.write_text(head + "NODATA_value -9999\n" + rows + "\n")
    with pytest.warns(T.NodataWarning, match="grid.asc': 1 of 480 samples"):
        d = T.read_heightmap(path)
    assert d.filled == d.nodata == 1 and d.spacing == (25.0, 25.0) and d.heights[3, 4] > 290
    _check_true_proportions(T.heightmap_terrain(d), (25.0, 25.0))
    # a .prj beside it says feet; a geographic grid without one is recognised by its numbers
    path.with_suffix(".prj").write_text(
        'PROJCS["NAD83 / x (ftUS)",GEOGCS["NAD83",UNIT["degree",0.0174532925199433]],'
        'UNIT["US survey foot",0.304800609601219]]'
    )
    with pytest.warns(T.NodataWarning):
        np.testing.assert_allclose(T.read_heightmap(path).spacing, 25 * 0.304800609601219)
    geo = tmp_path / "geo.asc"
    geo.write_text(
        "ncols 24\nnrows 20\nxllcenter -112.1\nyllcenter 36.1\ncellsize 0.000833333333\n"
        + rows
        + "\n"
    )
    with pytest.warns(T.NodataWarning, match="NODATA \\(-9999\\)"):  # the format's default
        d = T.read_heightmap(geo)
    assert d.crs == "geographic (assumed)" and d.nodata == 1
    truth = _ground_spacing(36.1 + 10 / 1200, -112.1, 1 / 1200, 1 / 1200)
    np.testing.assert_allclose(d.spacing, truth, rtol=0.01)


def _usgs_dem(path, profiles):
    """A USGS ASCII DEM of 30 m UTM profiles ``[(row offset, elevations)]``, metres."""
    header = bytearray(b" " * 1024)
    for (a, b), text in {
        (156, 162): "1",  # UTM
        (528, 534): "2",  # ground unit: metres
        (534, 540): "2",  # elevation unit: metres
        (816, 828): "0.300000D+02",  # x, y, z resolution
        (828, 840): "0.300000D+02",
        (840, 852): "0.100000D+01",
        (858, 864): str(len(profiles)),
    }.items():
        header[a:b] = text.rjust(b - a).encode()
    body = []
    for c, (row, elev) in enumerate(profiles):
        body += ["1", str(c + 1), str(len(elev)), "1", f"{30.0 * c}", f"{30.0 * row}", "0.0"]
        body += ["0", "0", *(str(e) for e in elev)]
    path.write_bytes(bytes(header) + " ".join(body).encode())


def test_nodata_marked_the_files_own_way_is_filled_counted_and_warned(tmp_path):
    # USGS DEM: a void (-32767) within a profile; the corners outside the quad (profiles
    # starting at other rows) are filled too, but they are no voids
    dem = tmp_path / "quad.dem"
    _usgs_dem(dem, [(0, [100, 101, 102, 103]), (1, [110, -32767, 112, 113]), (0, [120] * 4)])
    with pytest.warns(T.NodataWarning, match=r"quad.dem': 1 of 15 samples \(6.67 %\)"):
        d = T.read_heightmap(dem)
    assert d.nodata == 1 and d.filled == 4 and d.nodata_value == -32767
    assert np.all(np.isfinite(d.heights)) and 100 < d.heights[2, 1] < 125  # not -32767 m
    # GeoTIFF float32: the GDAL_NODATA tag's value in the map's own type, or NaN
    h = _hills(10, 12, 100.0, 300.0).astype(np.float32)
    h[4, 5] = np.float32(-9999.9)
    tif = tmp_path / "float.tif"
    _write_geotiff(tif, h, geographic=False, scale=(10.0, 10.0), nodata="-9999.9")
    with pytest.warns(T.NodataWarning, match=r"1 of 120 samples .* NODATA \(-9999.9\)"):
        d = T.read_heightmap(tif)
    assert d.nodata == 1 and d.heights.min() >= 99.0
    h[4, 5] = np.nan
    _write_geotiff(tif, h, geographic=False, scale=(10.0, 10.0), nodata="nan")
    with pytest.warns(T.NodataWarning, match=r"1 of 120 samples .* NODATA \(NaN\)"):
        assert T.read_heightmap(tif).nodata == 1
    # ESRI ASCII grid without a NODATA_value line: the format's default, -9999
    h = _hills(6, 8, 300.0, 1300.0)
    h[2, 3] = -9999
    asc = tmp_path / "default.asc"
    rows = "\n".join(" ".join(f"{v:.2f}" for v in row) for row in h)
    asc.write_text("ncols 8\nnrows 6\nxllcorner 0\nyllcorner 0\ncellsize 25\n" + rows + "\n")
    with pytest.warns(T.NodataWarning, match="default.asc': 1 of 48 samples"):
        d = T.read_heightmap(asc)
    assert d.nodata == 1 and d.nodata_value == -9999 and d.heights.min() >= 299.0
    # the terrain's mapping carries the count to the CLI's JSON line
    t = T.heightmap_terrain(d)
    assert t.mapping.to_dict()["nodata"] == {"count": 1, "fraction": round(1 / 48, 6)}


def test_unitless_relief_whatever_the_bit_depth(tmp_path):
    import imageio.v3 as iio

    from jaxgfx.cli.terrain import IMAGE_RELIEF_TEXT

    num, den = IMAGE_RELIEF_TEXT.split("/")
    assert int(num) / int(den) == T.IMAGE_RELIEF  # what --help says is what it does

    h = _hills(30, 40, 0.0, 1.0, seed=4)
    p8, p16 = tmp_path / "h8.png", tmp_path / "h16.png"
    iio.imwrite(p8, np.round(h * 255).astype(np.uint8))
    iio.imwrite(p16, np.round(h * 65535).astype(np.uint16))
    for p in (p8, p16, tmp_path / "h.npy"):
        if p.suffix == ".npy":
            np.save(p, h * 1e4)
        t = T.heightmap_terrain(T.read_heightmap(p))
        relief = float(np.max(np.asarray(t.heights)))
        # 1/8 of the longer side, never taller than the map is wide
        assert relief == pytest.approx(T.IMAGE_RELIEF * 40, rel=1e-5) and relief <= 30
        d = t.mapping.to_dict()
        assert d["metres_per_sample"] is None and d["metres_per_voxel"] is None


def test_apron_beyond_the_map_is_flat():
    h = np.random.default_rng(7).random((6, 8)) * 10
    t = T.heightmap_terrain(h, cell=2, vertical_scale=1.0)
    m = t.mapping
    border = np.concatenate([h[0], h[-1], h[:, 0], h[:, -1]]) - h.min()
    assert m.apron_height == pytest.approx(np.median(border), abs=1e-5)
    assert m.apron_fade == pytest.approx(max(T.APRON_FADE * 16, 2 * 2))
    # far beyond each edge and corner: the flat apron, also at 10^9
    far = np.array([-1e3, 1e3, 0.0, 0.0, -1e3, 1e3])
    farz = np.array([0.0, 0.0, -1e3, 1e3, -1e3, 1e3])
    g = np.asarray(T.ground_height(t, far, farz))
    np.testing.assert_allclose(g, m.base + m.apron_height, atol=HEIGHT_TOL)
    a = sample(t, (10**9, -2, 10**9), (4, 14, 4))
    col = np.arange(-2, 12) + 0.5 < m.base + m.apron_height
    assert (a == col[None, :, None]).all()
    # on the map and within half a cell of its edge the map itself: the apron starts there
    xs = m.origin[0] + np.array([0.0, 1.0, 16.0])
    g = np.asarray(T.ground_height(t, xs, np.full(3, m.origin[1] + 5.0)))
    np.testing.assert_allclose(
        g, heightfield_np(h, m, xs, np.full(3, m.origin[1] + 5.0)), atol=1e-3
    )
    # and it fades monotonically from the edge value to the apron over apron_fade
    xs = m.origin[0] + 16 + np.linspace(0, m.apron_fade, 20)
    g = np.asarray(T.ground_height(t, xs, np.full(20, 1.0)))
    assert np.all(np.diff(g) * np.sign(g[-1] - g[0]) >= -1e-5)


def test_volume_terrain_placed_and_tiled():
    vol = np.random.default_rng(1).random((5, 4, 3)) < 0.5
    off = (3, -2, 7)
    origin, shape = (-6, -4, -5), (20, 9, 21)
    g = grid_points(origin, shape) - np.asarray(off)
    placed = T.volume_terrain(vol, offset=off)
    inside = np.all((g >= 0) & (g < vol.shape), axis=-1)
    gc = np.clip(g, 0, np.asarray(vol.shape) - 1)
    want = inside & vol[gc[..., 0], gc[..., 1], gc[..., 2]]
    np.testing.assert_array_equal(sample(placed, origin, shape), want)
    tiled = T.volume_terrain(vol, offset=off, period=(7, 4))
    q = g.copy()
    q[..., 0] = np.mod(q[..., 0], 7)
    q[..., 2] = np.mod(q[..., 2], 4)
    inside = np.all((q >= 0) & (q < vol.shape), axis=-1)
    qc = np.clip(q, 0, np.asarray(vol.shape) - 1)
    want = inside & vol[qc[..., 0], qc[..., 1], qc[..., 2]]
    np.testing.assert_array_equal(sample(tiled, origin, shape), want)


def test_combinators():
    # Each combinator against its operands' samples, eagerly and by a jit of its own (not the
    # module's shared sample_jit), so that a fault of a compiled program and one of the
    # sampling tell themselves apart.
    a, b = T.SawTerrain(modulus=9, threshold=4), T.XorTerrain(modulus=5, threshold=2)
    origin, shape = (-5, 2, 11), (9, 8, 7)
    sa, sb = sample(a, origin, shape), sample(b, origin, shape)
    o = jnp.asarray(origin, jnp.int32)
    for combined, want in (
        (T.Union(a, b), sa | sb),
        (T.Intersection(a, b), sa & sb),
        (T.Difference(a, b), sa & ~sb),
    ):
        eager = np.asarray(T.sample_terrain(combined, o, level=0, shape=shape))
        np.testing.assert_array_equal(eager, want, err_msg=type(combined).__name__)
        jitted = jax.jit(T.sample_terrain, static_argnames=("shape",))(
            combined, o, level=0, shape=shape
        )
        np.testing.assert_array_equal(np.asarray(jitted), want, err_msg="jitted")
    f = T.as_terrain(lambda p: p[1] < 4)
    np.testing.assert_array_equal(sample(f, origin, shape), grid_points(origin, shape)[..., 1] < 4)


def test_terrain_function_wrong_output():
    with pytest.raises(TypeError, match="terrain must map"):
        T.check_terrain(lambda p: p[1].astype(jnp.float32))
    with pytest.raises(TypeError, match="terrain must map"):
        T.check_terrain(lambda p: p[:2] < 0)
    with pytest.raises(TypeError, match="terrain"):
        T.check_terrain(42)
    with pytest.raises(TypeError, match="terrain"):
        T.ClipBoxPipeline(lambda p: jnp.zeros((2,), bool), size=16, levels=1)


# ---------------------------------------------------------------- Clip-Box sampling and shifting


def test_sample_clipbox_levels_and_vmap():
    t = T.SawTerrain(modulus=13, threshold=6)
    for lvl in (0, 2):
        o = T.clipbox_origin(np.array([7, -3, 100]), lvl, N)
        assert np.all(o % (2 << lvl) == 0)
        box = clipbox_jit(t, jnp.asarray(o, jnp.int32), lvl, size=N)
        want = sample_np(lambda x, y, z: np.mod(x + y + z, 13) < 6, o, (N,) * 3, 1 << lvl)
        np.testing.assert_array_equal(np.asarray(box.voxels), want)
    origins = jnp.asarray([[0, 0, 0], [64, -32, 8]], jnp.int32)
    batched = jax.vmap(lambda o: T.sample_terrain(t, o, level=1, shape=(4, 4, 4)))(origins)
    for i in range(2):
        np.testing.assert_array_equal(batched[i], sample(t, origins[i], (4, 4, 4), level=1))


@pytest.mark.parametrize("delta", [(2, 0, 0), (-4, 2, 0), (6, -2, 4), (0, 0, -2)])
def test_shift_equals_resample_and_reuses(delta):
    t = T.XorTerrain(modulus=37, threshold=15)
    lvl = 1
    o = jnp.asarray(T.clipbox_origin(np.array([5, 9, -11]), lvl, N), jnp.int32)
    box = clipbox_jit(t, o, lvl, size=N)
    new = o + jnp.asarray(delta, jnp.int32) * (1 << lvl)
    d_vox = np.asarray(delta)
    moved = shift_jit(t, box, new, slabs=T.slab_thickness(d_vox))
    full = clipbox_jit(t, new, lvl, size=N)
    np.testing.assert_array_equal(moved.voxels, full.voxels)
    frac = T.reused_fraction(o, new, lvl, N)
    assert frac == pytest.approx(np.prod((N - np.abs(d_vox)) / N))
    if np.abs(d_vox).max() <= 2:
        assert frac >= 0.8  # thesis 3.4.6: about 80 % reused for small steps


def test_reuse_at_n128_for_a_few_voxels():
    # Host-side arithmetic only: a step of (3, 1, 2) voxels at N = 128 reuses
    # 125 * 127 * 126 / 128^3 = 95.4 %, well above the thesis's "about 80 %" (3.4.6).
    assert T.reused_fraction((0, 0, 0), (6, 2, 4), 1, 128) >= 0.95


def test_bad_sizes_and_levels():
    for bad in (15, 12, 4, 0):
        with pytest.raises(ValueError, match="size"):
            T.clipbox_origin((0, 0, 0), 0, bad)
    with pytest.raises(TypeError, match="size"):
        T.ClipBoxPipeline(T.XorTerrain(), size=16.0, levels=2)
    with pytest.raises(ValueError, match="levels"):
        T.ClipBoxPipeline(T.XorTerrain(), size=16, levels=0)
    with pytest.raises(ValueError, match="levels"):
        T.nested_origins((0, 0, 0), levels=0, size=16)
    with pytest.raises(ValueError, match="viewer"):
        T.clipbox_origin((0.5, 0, 0), 0, 16)
    with pytest.raises(ValueError, match="level"):
        T.clipbox_origin((0, 0, 0), -1, 16)


def test_pattern_filter_matches_numpy():
    v = np.random.default_rng(5).random((6, 5, 7)) < 0.4
    got = np.asarray(jax.jit(T.pattern_filter)(jnp.asarray(v)))
    want = v.copy()
    for a, b in ((0, 1), (0, 2), (1, 2)):
        it = np.ndindex(*[s - 1 if ax in (a, b) else s for ax, s in enumerate(v.shape)])
        for idx in it:
            cells = []
            for da, db in ((0, 0), (1, 0), (0, 1), (1, 1)):
                j = list(idx)
                j[a] += da
                j[b] += db
                cells.append(tuple(j))
            val = [v[c] for c in cells]
            if (val[0] and val[3] and not val[1] and not val[2]) or (
                val[1] and val[2] and not val[0] and not val[3]
            ):
                for c in cells:
                    want[c] = True
    np.testing.assert_array_equal(got, want)


# ---------------------------------------------------------------- voxels -> polygons


def edge_counts(mesh, mask, directed=False):
    f = np.asarray(mesh.faces)[np.asarray(mask)]
    p = np.round(
        np.asarray(mesh.vertices, np.float64) + np.asarray(getattr(mesh, "origin", 0)), ROUND
    )
    out = Counter()
    for a, b in ((0, 1), (1, 2), (2, 0)):
        for x, y in zip(map(tuple, p[f[:, a]]), map(tuple, p[f[:, b]])):
            out[(x, y) if directed else tuple(sorted((x, y)))] += 1
    return out


def test_mesh_of_enclosed_blob_is_closed_and_oriented():
    # A solid blob that does not touch the box: the mesh must be closed, consistently
    # oriented, and enclose exactly the solid voxels (divergence theorem).
    rng = np.random.default_rng(2)
    vox = np.zeros((N, N, N), bool)
    vox[3:13, 4:12, 2:14] = rng.random((10, 8, 12)) < 0.7
    box = T.ClipBox(jnp.asarray([8, -16, 4], jnp.int32), jnp.asarray(vox), jnp.asarray(1), N)
    m = mesh_jit(box)  # the blob stays clear of the seam ring
    assert not bool(m.overflow)
    pairs = sum(int(np.sum(np.diff(vox.astype(np.int8), axis=d) != 0)) for d in range(3))
    assert int(m.num_quads) == pairs
    valid = np.asarray(m.face_valid)
    assert valid.sum() == 2 * pairs
    und = edge_counts(m, valid)
    assert all(c % 2 == 0 for c in und.values())
    dirs = edge_counts(m, valid, directed=True)
    assert all(dirs[(a, b)] == dirs[(b, a)] for a, b in dirs)
    f = np.asarray(m.faces)[valid]
    p = np.asarray(m.vertices, np.float64)
    vol = np.sum(np.einsum("ij,ij->i", p[f[:, 0]], np.cross(p[f[:, 1]], p[f[:, 2]]))) / 6.0
    assert vol == pytest.approx(vox.sum() * 2.0**3)
    # vertices are shared lattice corners: no duplicates among used vertices
    used = np.asarray(m.vertices)[: int(m.num_vertices)]
    assert len({tuple(r) for r in used}) == used.shape[0]


def quads_reference(occ: np.ndarray, seam: bool) -> set:
    """NumPy reference of 3.4.4: every solid/air face as two triangles of lattice corners
    (counter-clockwise from the air), after the seam snap; degenerate ones dropped."""
    n = occ.shape[0]
    eye = np.eye(3, dtype=np.int64)
    out = set()
    for d in range(3):
        lo = np.take(occ, np.arange(n - 1), axis=d)
        hi = np.take(occ, np.arange(1, n), axis=d)
        for p in np.argwhere(lo != hi):
            base = p + eye[d]
            e_u, e_v = eye[(d + 1) % 3], eye[(d + 2) % 3]
            solid_below = lo[tuple(p)]
            c1, c3 = (base + e_u, base + e_v) if solid_below else (base + e_v, base + e_u)
            cs = [base, c1, base + e_u + e_v, c3]
            if seam:
                cs = [c - (c & 1) if np.any((c == 0) | (c == n)) else c for c in cs]
            for t in ((0, 1, 2), (0, 2, 3)):
                tri = [tuple(int(v) for v in cs[i]) for i in t]
                if len(set(tri)) == 3:
                    r = tri.index(min(tri))
                    out.add(tuple(tri[r:] + tri[:r]))
    return out


def test_mesh_matches_numpy_reference():
    # The word-parallel mesher gives exactly the reference quads (as
    # lattice triangles), each vertex once, and vertex_id inverts the lattice.
    rng = np.random.default_rng(5)
    vox = np.zeros((N, N, N), bool)
    vox[:, :7] = True
    vox[2:14, 5:11, 1:15] = rng.random((12, 6, 14)) < 0.5
    box = T.ClipBox(jnp.asarray([0, -8, 0], jnp.int32), jnp.asarray(vox), jnp.asarray(0), N)
    for seam in (True,):  # seam=False is the same code without the snap; one compile
        m = mesh_jit(box, seam=seam)
        assert not bool(m.overflow)
        lat = np.asarray(m.lattice)
        f = np.asarray(m.faces)[np.asarray(m.face_valid)]
        got = set()
        for t in lat[f]:
            tri = [tuple(int(v) for v in c) for c in t]
            r = tri.index(min(tri))
            got.add(tuple(tri[r:] + tri[:r]))
        occ = np.asarray(T.seam_occupancy(jnp.asarray(vox))) if seam else vox
        assert got == quads_reference(occ, seam) and len(got) == len(f)
        used = lat[: int(m.num_vertices)]
        assert len({tuple(r) for r in used}) == used.shape[0] == len(np.unique(f))
        vid = np.asarray(m.vertex_id(jnp.asarray(used)))
        np.testing.assert_array_equal(vid, np.arange(used.shape[0]))


def test_mesh_overflow_is_reported_not_hidden():
    vox = np.indices((N, N, N)).sum(0) % 2 == 0  # checkerboard: every face is a quad
    box = T.ClipBox(jnp.zeros(3, jnp.int32), jnp.asarray(vox), jnp.asarray(0), N)
    m = mesh_jit(box, max_quads=1000)
    occ = np.asarray(T.seam_occupancy(jnp.asarray(vox)))
    pairs = sum(int(np.sum(np.diff(occ.astype(np.int8), axis=d) != 0)) for d in range(3))
    assert bool(m.overflow) and int(m.num_quads) == pairs > 1000


TERRAINS = {
    "saw": T.SawTerrain(modulus=40, threshold=20),
    "xor": T.XorTerrain(modulus=64, threshold=23),
    "sin": T.SinTerrain(),
    "csg": T.random_csg_terrain(
        key=jax.random.PRNGKey(0),
        count=300,
        period=256,
        y_range=(-32, 32),
        radius=(2, 8),
        bin_size=16,
    ),
    "heightmap": T.heightmap_terrain(
        np.random.default_rng(0).random((9, 7)) * 12, cell=3, vertical_scale=1.0, base=-6
    ),
}


@pytest.mark.parametrize("smooth", [False, True])
@pytest.mark.parametrize("name", sorted(TERRAINS))
def test_zero_cracks_between_two_levels(name, smooth):
    t = TERRAINS[name]
    build = smooth_jit if smooth else mesh_jit
    for viewer in ([5, 3, 7], [-37, 1, 1_000_000_100]):
        o0 = T.clipbox_origin(np.array(viewer), 0, N)
        o1 = T.clipbox_origin(np.array(viewer), 1, N)
        b0 = clipbox_jit(t, jnp.asarray(o0, jnp.int32), 0, size=N)
        b1 = clipbox_jit(t, jnp.asarray(o1, jnp.int32), 1, size=N)
        inner, outer = build(b0), build(b1)
        assert not bool(inner.overflow) and not bool(outer.overflow)
        inner = weld_jit(inner, outer)
        e_in = edge_counts(inner, inner.face_valid)
        e_out = edge_counts(outer, vis_jit(outer, jnp.asarray(o0, jnp.int32), N))
        inner_open = [k for k, c in e_in.items() if c % 2]
        # every boundary edge of the inner mesh is an edge of the visible outer mesh
        assert all(e_out.get(k, 0) % 2 == 1 for k in inner_open)
        # and the union is closed except on the outer box's own boundary
        lat = np.asarray(outer.lattice)[: int(outer.num_vertices)]
        pos = np.round(np.asarray(outer.vertices, np.float64) + np.asarray(outer.origin), ROUND)
        rim = np.any((lat == 0) | (lat == N), axis=-1)
        rim_keys = {tuple(q) for q in pos[: lat.shape[0]][rim]}
        for k, c in (e_in + e_out).items():
            if c % 2:
                assert k[0] in rim_keys and k[1] in rim_keys, (name, k)
        if name in ("saw", "csg", "heightmap"):
            assert len(inner_open) > 0  # the surface does cross the seam


def test_visible_faces_excludes_inner_region():
    t = TERRAINS["saw"]
    o1 = T.clipbox_origin(np.array([0, 0, 0]), 1, N)
    o0 = T.clipbox_origin(np.array([0, 0, 0]), 0, N)
    m = mesh_jit(clipbox_jit(t, jnp.asarray(o1, jnp.int32), 1, size=N))
    vis = np.asarray(vis_jit(m, jnp.asarray(o0, jnp.int32), N))
    c = np.asarray(m.face_center2) / 2.0 * 2 + np.asarray(o1)  # world centre of each face
    inside = np.all((c > o0) & (c < o0 + N), axis=-1)
    np.testing.assert_array_equal(vis, np.asarray(m.face_valid) & ~inside)
    assert inside[np.asarray(m.face_valid)].any() and vis.any()


def test_smoothing_and_normals():
    flat = T.as_terrain(lambda p: p[1] < 6)
    box = clipbox_jit(flat, jnp.asarray([0, 0, 0], jnp.int32), 0, size=N)
    m = smooth_jit(box)
    used = int(m.num_vertices)
    n = np.asarray(m.normals)[:used]
    # The seam ring (lattice <= 2) is drawn at the outer level's cube offset, half a
    # voxel lower; 3 smoothing steps carry that 3 links in (and normals one more).
    xz = np.asarray(m.lattice)[:used][:, [0, 2]]
    inner = np.all((xz > 2 + 3 + 1) & (xz < N - 2 - 3 - 1), -1)
    assert inner.sum() >= 9
    np.testing.assert_allclose(n[inner], np.tile([0.0, 1.0, 0.0], (inner.sum(), 1)), atol=1e-6)
    blob = TERRAINS["csg"]
    m0 = mesh_jit(clipbox_jit(blob, jnp.asarray([0, -8, 0], jnp.int32), 0, size=N))
    ms = PIPE.normals_fn(PIPE.smooth_fn(m0, iterations=3))
    assert np.all(np.isfinite(np.asarray(ms.vertices)))
    nn = np.linalg.norm(np.asarray(ms.normals)[: int(ms.num_vertices)], axis=-1)
    np.testing.assert_allclose(nn, 1.0, atol=1e-5)

    def rough(m):  # sum of squared lengths of the vertex-to-vertex links
        nb = np.asarray(m.neighbors)
        p = np.asarray(m.vertices)
        i, k = np.nonzero(nb >= 0)
        return float(np.sum((p[i] - p[nb[i, k]]) ** 2))

    assert rough(ms) < rough(m0)

    def loss(verts):
        m = dataclasses.replace(m0, vertices=verts)
        m = T.mesh_normals(T.smooth_mesh(m, iterations=2))
        return jnp.sum(m.normals[:, 1] * jnp.linspace(0.0, 1.0, m.normals.shape[0]))

    g = jax.grad(loss)(m0.vertices)
    assert np.all(np.isfinite(np.asarray(g)))
    check_grads(
        lambda v: T.smooth_mesh(dataclasses.replace(m0, vertices=v), iterations=2).vertices,
        (m0.vertices,),
        order=1,
        modes=("rev",),
        atol=1e-2,
        rtol=1e-2,
    )


# ---------------------------------------------------------------- nested boxes and the worker


@pytest.fixture(scope="module")
def pipeline():
    return PIPE


def test_nested_pipeline_moves_and_stays_exact(pipeline):
    st = pipeline.init(np.array([0, 3, 0]))
    assert st.levels == 3
    path = [np.array([0, 3, 2 * i]) for i in range(1, 8)]
    moved = Counter()
    for v in path:
        st, stats = pipeline.update(st, v)
        for lvl, s in stats.items():
            moved[lvl] += 1
            assert 0.0 <= s["reused"] <= 1.0
        origins = st.origins()
        for lvl in range(2):
            assert T.is_nested(origins[lvl], origins[lvl + 1], lvl, N)
    assert moved[0] > moved[1] >= moved[2]  # inner boxes follow the viewer more often
    for lvl, b in enumerate(st.boxes):  # cached + differential == sampled from scratch
        fresh = clipbox_jit(pipeline.terrain, b.origin, lvl, size=N)
        np.testing.assert_array_equal(b.voxels, fresh.voxels)


def pipeline_on(terrain):
    """PIPE's jitted steps on another terrain (no new compilation of the meshing steps)."""
    pipe = copy.copy(PIPE)
    pipe.terrain, pipe.capacity = terrain, {}
    return pipe


# A smooth periodic height map (period 64 = the level-2 box, so no tile seam).
_G = np.arange(64) * 2 * np.pi / 64
SMOOTH_MAP = 7 * np.sin(_G)[None, :] + 5 * np.cos(2 * _G + 1)[:, None]


SNAP_TOL = 0.02
"""Voxels: a snapped vertex's height above the surface (float32 bilinear, two origins)."""


@pytest.mark.parametrize("viewer", [(5, 2, 7), (40, -3, 21)])
@pytest.mark.parametrize("snap", [False, True])
def test_levels_lie_on_the_same_surface(viewer, snap):
    # Every level, its seam ring included, is an unbiased estimate of
    # the same surface.  A level-l voxel drawn as [p, p + 2^l] stood (2^l - 1) / 2 too
    # high on average, and the ring (the outer level's samples) smoothed at the inner
    # level's strength stood up to an outer voxel above both neighbours: flat-topped
    # slabs along every box border.  With snap (the default for height maps) every
    # vertex but the seam ring's lies on the surface itself.
    t = T.heightmap_terrain(SMOOTH_MAP, vertical_scale=1.0, base=-12, origin=(0, 0), wrap=True)
    pipe = pipeline_on(t)
    pipe.snap = snap
    st = pipe.init(np.array(viewer))
    for lvl, lv in enumerate(T.level_views(st)):
        p = lv["vertices"].astype(np.float64) + lv["origin"]
        f = lv["faces"][lv["visible"]]

        def err(q):  # height above the terrain's own surface under q
            return q[:, 1] - np.asarray(T.ground_height(t, q[:, 0], q[:, 2]), np.float64)

        drawn = p[np.unique(f)]
        assert np.abs(err(drawn)).max() <= (1 << lvl) + 1.5, lvl
        fn = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
        up = fn[:, 1] > 0.5 * np.linalg.norm(fn, axis=1)
        assert abs(err(p[f[up]].mean(axis=1)).mean()) <= 0.25 * (1 << lvl) + 0.25, lvl
        if snap:
            # only the seam ring (the outer mesh's vertices and their midpoints) is off
            lat = np.asarray(st.meshes[lvl].lattice)[np.unique(f)]
            ring = np.any((lat <= 1) | (lat >= N - 1), -1) & (lvl < st.levels - 1)
            assert np.abs(err(drawn[~ring])).max() <= SNAP_TOL, lvl
            assert np.abs(err(drawn[ring])).max(initial=0.0) <= (1 << lvl) + 0.5, lvl


def test_snap_to_surface_is_exact_far_away():
    # The snap subtracts the integer origins in int32: the same mesh 10^9 voxels away
    # (map and box moved together) gets bit-identical vertices.
    h = np.add.outer(np.arange(5.0), 2 * np.arange(6.0)) ** 1.5
    v = jnp.asarray(np.random.default_rng(0).uniform(-3, 9, (64, 3)), jnp.float32)
    snap = jax.jit(lambda t, o, v: t.snap_to_surface(o, v))
    got = []
    for shift, up in ((0, 0), (10**9, 2**23)):  # heights are float32 below 2^24
        t = T.heightmap_terrain(h, cell=1.5, origin=(shift + 0.25, -shift), base=up - 3)
        got.append(np.asarray(snap(t, jnp.asarray([shift, up, -shift], jnp.int32), v)))
    np.testing.assert_array_equal(got[0], got[1])
    t = T.heightmap_terrain(h, cell=1.5, origin=(0.25, 0), base=-3)
    g = np.asarray(T.ground_height(t, v[:, 0], v[:, 2]))
    np.testing.assert_allclose(got[0][:, 1], g, atol=1e-4)
    np.testing.assert_array_equal(got[0][:, [0, 2]], np.asarray(v)[:, [0, 2]])


def _seam_pair():
    """Smoothed level-0 and level-1 meshes of a small height map, the level-0 one with a seam."""
    t = T.heightmap_terrain(SMOOTH_MAP, vertical_scale=1.0, base=-12, origin=(0, 0), wrap=True)
    viewer = np.array([5, 2, 7])
    b0, b1 = (
        clipbox_jit(t, jnp.asarray(T.clipbox_origin(viewer, lvl, N), jnp.int32), lvl, size=N)
        for lvl in (0, 1)
    )
    inner, outer = smooth_jit(b0), smooth_jit(b1)
    return inner, outer


def test_blend_keeps_the_seam_and_settles():
    # blend_seam (the pipeline's weld) relaxes only the band inside the ring: the
    # ring stays on the outer surface, and re-welding a blended mesh barely moves it.
    inner, outer = _seam_pair()
    welded = jax.jit(T.weld_seam)(inner, outer)
    blended = PIPE.weld_fn(inner, outer)
    used = int(inner.num_vertices)
    lat = np.asarray(inner.lattice)[:used]
    ring = np.any((lat <= 1) | (lat >= N - 1), -1)
    moved = np.abs(np.asarray(blended.vertices) - np.asarray(welded.vertices))[:used].max(-1)
    assert ring.any() and moved[ring].max() == 0.0
    assert moved[~ring].max() > 0.05  # the band did move
    deep = np.all((lat > 2 + 3) & (lat < N - 2 - 3), -1)
    assert moved[deep].max() == 0.0
    again = PIPE.weld_fn(blended, outer)
    assert np.abs(np.asarray(again.vertices) - np.asarray(blended.vertices)).max() < 0.25


def test_blend_compact_rows_equal_every_row(monkeypatch, user_jit):
    # weld_seam / blend_seam work on compacted ring and band rows when they fit their
    # lists, on every row otherwise: both paths give bit-identical meshes on XLA:CPU.  (On
    # an H100, XLA:GPU fused the normals' normalisation differently per path: 1 ulp.)
    from jaxgfx._src.terrain import meshing, postprocess

    inner, outer = _seam_pair()
    outs = []
    for share in (1, 1 << 30):  # every ring/band row fits the list / none does
        monkeypatch.setattr(meshing, "_RING_SHARE", share)
        monkeypatch.setattr(postprocess, "_BAND_SHARE", share)
        # a fresh function each time: jax.jit caches traces per function object
        # (two programs compared bit for bit: at the user's code generation)
        outs.append(user_jit(lambda i, o: postprocess.blend_seam(i, o))(inner, outer))
    ulps = 0 if jax.default_backend() == "cpu" else 1
    for field in ("vertices", "normals"):
        a, b = (np.asarray(getattr(o, field)) for o in outs)
        np.testing.assert_array_max_ulp(a, b, maxulp=ulps)
    assert np.abs(np.asarray(outs[0].vertices) - np.asarray(inner.vertices)).max() > 0.05


@pytest.mark.parametrize("name", ["saw", "csg"])
def test_exported_mesh_is_one_surface(name):
    # The levels welded into one surface -- no duplicate vertices,
    # no edge in more than two triangles, open edges only on the outermost rim.
    viewer = np.array([5, 3, 7])
    st = pipeline_on(TERRAINS[name]).init(viewer)
    views = T.level_views(st)
    tm = T.mesh_to_trimesh(views, viewer)
    v, f = np.asarray(tm.vertices), np.asarray(tm.faces)
    assert len(f) > 100 and len(np.unique(v, axis=0)) == len(v)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    assert count.max() <= 2
    assert tm.is_winding_consistent
    # the rim: outermost-box vertices on lattice 0 or N, anchored as level_arrays does
    out = st.meshes[-1]
    used = int(out.num_vertices)
    lat = np.asarray(out.lattice)[:used]
    shift = (views[-1]["origin"] - viewer).astype(np.float32)
    rim_pos = (views[-1]["vertices"][:used] + shift)[np.any((lat == 0) | (lat == N), -1)]
    rim = {tuple(q) for q in rim_pos.astype(np.float32)}
    on_rim = np.array([tuple(q) in rim for q in v.astype(np.float32)])
    open_e = edges[count == 1]
    assert len(open_e) > 0 and np.all(on_rim[open_e[:, 0]] & on_rim[open_e[:, 1]])
    # the levels as drawn share their seam vertices: that is what the weld removes
    raw = T.mesh_to_trimesh(views, viewer, weld=False)
    assert len(np.unique(np.asarray(raw.vertices), axis=0)) < len(raw.vertices)


def test_an_opencv_camera_sees_what_its_rays_meet(raster_jit):
    # The Clip-Box terrain drawn through a COLMAP-like camera (fx != fy, principal point
    # off centre, rolled; relative to the viewer as the terrain draws): its depth is that
    # of the camera's pixel rays, written from K, R and t alone, met by trimesh on the
    # levels' drawn faces.
    from experiments.camera_models import (
        opencv_intrinsics,
        opencv_look_at,
        opencv_pixel_rays,
        trimesh_depth,
    )
    from jaxgfx.camera import camera_from_opencv

    viewer = np.array([5, 3, 7])
    views = T.level_views(pipeline_on(TERRAINS["saw"]).init(viewer))
    K = opencv_intrinsics(64, 48, 70.0)
    R, t = opencv_look_at([-3.0, 14.0, -30.0], [0.0, -6.0, 4.0], roll=8.0)
    cam = camera_from_opencv(K, R, t, 64, 48, near=0.05, far=500.0)
    frame = T.render_levels(cam, views, viewer, rasterize_fn=raster_jit)
    v, _, f, _ = T.level_arrays(views, viewer)
    ref = trimesh_depth(v, f, *opencv_pixel_rays(K, R, t, 64, 48))
    ours = np.asarray(frame.depth)
    assert 0.3 < np.isfinite(ref).mean()
    hit = np.isfinite(ref) & np.isfinite(ours)
    span = ref[np.isfinite(ref)].max() - ref[np.isfinite(ref)].min()
    gap = np.abs(np.where(hit, ours, 0.0) - np.where(hit, ref, 0.0))
    same = (np.isfinite(ref) == np.isfinite(ours)) & (gap <= 1e-3 * span)
    assert same.mean() >= 0.995, same.mean()


def test_exported_snapped_heightmap_is_one_surface():
    # Snapped onto a rugged height map, thin wall slivers fold over each other, and the
    # faces around an edge where voxels touch are paired by the voxel lattice instead
    # (paired by the snapped positions, this map left 19 edges in four triangles).
    h = np.random.default_rng(2).uniform(0, 14, (32, 32))
    t = T.heightmap_terrain(h, vertical_scale=1.0, base=-8, origin=(0, 0), wrap=True)
    viewer = np.array([5, 3, 7])
    views = T.level_views(pipeline_on(t).init(viewer))

    def most_faces_on_an_edge(f):
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        return np.unique(e, axis=0, return_counts=True)[1].max()

    tm = T.mesh_to_trimesh(views, viewer)
    assert len(tm.faces) > 100 and most_faces_on_an_edge(np.asarray(tm.faces)) == 2
    v, n, f, _ = T.level_arrays(views, viewer)
    assert most_faces_on_an_edge(T.weld_mesh(v, n, f)[2]) > 2  # the case is a real one


WORKER_SWAPS = 8  # the stress test ends after this many buffer hand-overs
WORKER_MAX_FRAMES = 5000  # safety bound only: a stuck worker fails instead of hanging


def test_worker_stress_never_torn(pipeline):
    # Bounded by events, not wall time: the renderer draws frames until the worker has
    # handed over WORKER_SWAPS complete buffers.  The renderer moves the viewer 3 voxels
    # after each frame, so the path is a function of the frame number; the first frame
    # is drawn before the viewer moves, so it swaps nothing (frames > swaps).
    worker = T.GeometryWorker(pipeline, np.array([0, 3, 0]))
    worker.start()
    frames, gens = 0, []
    try:
        while worker.swaps < WORKER_SWAPS:
            assert frames < WORKER_MAX_FRAMES, f"only {worker.swaps} swaps in {frames} frames"
            buf = worker.acquire()
            s0 = buf["stamp"].copy()
            assert s0[0] == s0[1]
            sums = [float(np.sum(lv["vertices"], dtype=np.float64)) for lv in buf["levels"]]
            time.sleep(0.003)  # "draw": the worker must not touch this buffer meanwhile
            assert np.array_equal(buf["stamp"], s0)
            for lv, s in zip(buf["levels"], sums):
                assert lv["generation"] == s0[0]
                assert s == lv["checksum"]
                assert float(np.sum(lv["vertices"], dtype=np.float64)) == s
            gens.append(int(s0[0]))
            frames += 1
            z = 3 * frames
            worker.set_viewer(np.array([z % 97, 3, z]))
    finally:
        worker.stop()
    assert worker.swaps >= 5 and frames > worker.swaps
    assert gens == sorted(gens)  # generations only move forward


# ---------------------------------------------------------------- subdivision, CLI


def blob_mesh():
    rng = np.random.default_rng(2)
    vox = np.zeros((N, N, N), bool)
    vox[3:13, 4:12, 2:14] = rng.random((10, 8, 12)) < 0.7
    box = T.ClipBox(jnp.asarray([8, -16, 4], jnp.int32), jnp.asarray(vox), jnp.asarray(1), N)
    return PIPE.normals_fn(mesh_jit(box)), vox


def test_subdivision_with_displacement_stays_closed():
    m, vox = blob_mesh()
    key = jax.random.PRNGKey(7)
    sub = PIPE.subdivide_fn(m, key=key, amplitude=0.3)
    flat = PIPE.subdivide_fn(m, key=key, amplitude=0.0)
    valid = np.asarray(sub.face_valid)
    assert valid.sum() == 4 * np.asarray(m.face_valid).sum()
    for s in (sub, flat):
        e = edge_counts(s, s.face_valid)
        assert all(c % 2 == 0 for c in e.values())  # midpoints agree across each edge
        assert np.all(np.isfinite(np.asarray(s.vertices)))
    f = np.asarray(flat.faces)[valid]
    p = np.asarray(flat.vertices, np.float64)
    vol = np.sum(np.einsum("ij,ij->i", p[f[:, 0]], np.cross(p[f[:, 1]], p[f[:, 2]]))) / 6.0
    assert vol == pytest.approx(vox.sum() * 8.0)
    d = np.abs(np.asarray(sub.vertices) - np.asarray(flat.vertices)).max()
    assert 0 < d <= 0.3 * 2 + 1e-5  # level 1: amplitude 0.3 voxels of size 2
    again = PIPE.subdivide_fn(m, key=key, amplitude=0.3)
    np.testing.assert_array_equal(sub.vertices, again.vertices)  # same key, same details


def _terrain_cli(tmp_path, *extra: str) -> int:
    """``jaxgfx terrain`` through the CLI's entry point, small and fast by default."""
    from jaxgfx.cli import main

    # (x + y + z) mod 1000 = 510: air, 6 voxels above a slab of f_SAW
    small = ["--function", "saw", "--viewer", "0,510,0", "--resolution", "16", "--levels", "2"]
    size = ["--size", "32x24", "--smoothing", "2", "--out", str(tmp_path / "a.png")]
    return main(["terrain", *small, *size, *extra])


def test_cli_terrain_errors(tmp_path, capsys):
    assert _terrain_cli(tmp_path, "--function", "nope") == 2
    assert "--function" in capsys.readouterr().err
    missing = "heightmap:" + str(tmp_path / "missing.dem")
    assert _terrain_cli(tmp_path, "--function", missing) == 2
    assert "heightmap path" in capsys.readouterr().err
    # a directory, and a text file named .png: one line naming the file and the cause
    assert _terrain_cli(tmp_path, "--function", f"heightmap:{tmp_path}") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{str(tmp_path)!r} is a directory" in err
    fake = tmp_path / "notes.png"
    fake.write_text("not a picture\n")
    assert _terrain_cli(tmp_path, "--function", f"heightmap:{fake}") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{str(fake)!r} is not a readable image" in err
    assert "pip" not in err
    assert _terrain_cli(tmp_path, "--resolution", "15") == 2
    assert "--resolution" in capsys.readouterr().err
    assert _terrain_cli(tmp_path, "--levels", "0") == 2
    assert "levels" in capsys.readouterr().err
    # too many levels for the int32 world: one line naming --levels and the most that work
    assert _terrain_cli(tmp_path, "--levels", "25") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("jaxgfx terrain: error: --levels must be <= 21 with --resolution 16")
    assert _terrain_cli(tmp_path, "--cell", "2") == 2
    assert "--cell applies to --function heightmap" in capsys.readouterr().err
    assert _terrain_cli(tmp_path, "--depth", str(tmp_path / "d.png")) == 2
    assert "--depth" in capsys.readouterr().err
    assert _terrain_cli(tmp_path, "--viewer", "0,24,0") == 2  # inside a slab
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--viewer (0, 24, 0) is inside solid ground" in err
    assert not (tmp_path / "a.png").exists()


def test_cli_terrain_heightmap_renders_prints_its_mapping_and_exports(hill, tmp_path, capsys):
    import imageio.v3 as iio
    import trimesh

    from jaxgfx.cli import main

    h, path = hill
    depth, mesh = tmp_path / "d.npy", tmp_path / "t.ply"
    small = ["--resolution", "16", "--levels", "2", "--size", "32x24", "--smoothing", "2"]
    fn = ["--function", f"heightmap:{path}", "--cell", "2", "--vertical-scale", "0.5"]
    outs = ["--out", str(tmp_path / "a.png"), "--depth", str(depth)]
    assert main(["terrain", *small, *fn, *outs, "--mesh", str(mesh)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1
    out = json.loads(lines[0])
    t = T.heightmap_terrain(h, cell=2, vertical_scale=0.5)
    want = t.mapping.to_dict()
    assert {k: out[k] for k in want} == want
    # the default viewer stands above the map centre, in air
    assert out["viewer"] == list(T.default_viewer(t)) and out["viewer"][1] > 0.5 * 30
    img = iio.imread(tmp_path / "a.png")
    assert img.shape[:2] == (24, 32) and img.std() > 0
    d = np.load(depth)
    assert d.shape == (24, 32) and np.isfinite(d).any() and np.isinf(d).any()
    tm = trimesh.load(mesh, process=False)
    assert len(tm.faces) == out["mesh_triangles"] > 0 and np.all(np.isfinite(tm.vertices))
    # a viewer inside the ground: an error naming --viewer, or a warning with --allow-inside
    # (same map and sizes as above: the compiled pipeline is reused)
    assert main(["terrain", *small, *fn, *outs, "--viewer", "0,0,0"]) == 2
    assert "--allow-inside" in capsys.readouterr().err
    assert main(["terrain", *small, *fn, *outs, "--viewer", "0,0,0", "--allow-inside"]) == 0
    cap = capsys.readouterr()
    assert "warning: --viewer (0, 0, 0) is inside solid ground" in cap.err
    assert json.loads(cap.out)["viewer"] == [0, 0, 0]


def test_cli_terrain_geotiff_prints_its_scale(tmp_path, capsys):
    from jaxgfx.cli import main

    h = np.round(_hills(20, 24, 700, 1500)).astype(np.int16)
    h[3, 4] = -32768  # a void: filled, reported in the JSON line and warned about
    path = tmp_path / "dem.tif"
    _write_geotiff(path, h, geographic=True, nodata=-32768)
    small = ["--resolution", "16", "--levels", "2", "--size", "32x24", "--smoothing", "2"]
    out = ["--out", str(tmp_path / "a.png")]
    assert main(["terrain", *small, "--function", f"heightmap:{path}", *out]) == 0
    cap = capsys.readouterr()
    rep = json.loads(cap.out)
    assert rep["nodata"] == {"count": 1, "fraction": round(1 / 480, 6)}
    assert cap.err == (
        f"jaxgfx terrain: warning: heightmap {str(path)!r}: 1 of 480 samples (0.208 %) are "
        "NODATA (-32768), filled from their neighbours\n"
    )
    truth = _ground_spacing(46.5 - 10 / 1200, -122.5, 1 / 1200, 1 / 1200)
    np.testing.assert_allclose(rep["metres_per_sample"], truth, rtol=0.01)
    mpv = rep["metres_per_voxel"]
    np.testing.assert_allclose(mpv, mpv[0], rtol=1e-6)
    assert rep["crs"] == "EPSG:4326" and rep["edge"] == "apron"
    assert rep["cell"][0] == 1.0 and rep["cell"][1] == pytest.approx(truth[1] / truth[0])


def test_levels_are_limited_by_the_int32_world_before_any_work():
    assert T.max_levels(16) == T.max_levels(256) == 21  # levels 0..20
    assert T.max_levels(1024) == 19  # 2 N 2^L voxels around the viewer fit int32
    assert T.max_levels(2**28) == 1
    with pytest.raises(ValueError, match=r"levels must be <= 21 for boxes of size 16.*got 25"):
        T.ClipBoxPipeline(T.SawTerrain(), size=16, levels=25)
    with pytest.raises(ValueError, match="levels must be <= 19 for boxes of size 1024"):
        T.nested_origins(np.zeros(3, np.int64), levels=20, size=1024)


def test_subdivision_needs_a_key_and_views_draw_it(pipeline):
    st = pipeline.init(np.array([0, 3, 0]))
    with pytest.raises(ValueError, match="key"):
        T.level_views(st, subdivide=1)
    with pytest.raises(ValueError, match="key"):
        T.ClipBoxPipeline(T.XorTerrain(), size=16, levels=2, subdivide=1)
    plain = T.level_views(st)
    sub = T.level_views(st, subdivide=1, key=jax.random.PRNGKey(0), subdivide_fn=PIPE.subdivide_fn)
    assert sub[0]["visible"].sum() == 4 * plain[0]["visible"].sum()
    for a, b in zip(plain[1:], sub[1:]):
        np.testing.assert_array_equal(a["faces"], b["faces"])
    v, n, f, lvl = T.level_arrays(sub, (0, 3, 0))
    assert f.max() < v.shape[0] and np.all(np.isfinite(v))
