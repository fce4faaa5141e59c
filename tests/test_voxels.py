"""Voxel inputs, surface extraction and the RLE structure (thesis 4.3, 4.4.6, 4.4.7)."""

from __future__ import annotations

import functools
import struct
import types

import jax
import numpy as np
import pytest

from jaxgfx import raycast as V
from jaxgfx.camera import look_at


def _random_voxels(rng, shape, n):
    c = np.stack([rng.integers(0, s, n) for s in shape], axis=1)
    col = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    return V.make_voxels(c, col, shape)


def _same(a: V.Voxels, b: V.Voxels):
    ka = np.ravel_multi_index(np.asarray(a.coords, np.int64).T, a.shape)
    kb = np.ravel_multi_index(np.asarray(b.coords, np.int64).T, b.shape)
    ia, ib = np.argsort(ka), np.argsort(kb)
    assert a.shape == b.shape
    np.testing.assert_array_equal(ka[ia], kb[ib])
    np.testing.assert_array_equal(a.colors[ia], b.colors[ib])


def _decode_column_numpy(first, rest, height):
    """Slow reference decoder for one column: list of (y, colour slot)."""
    ys = []
    y = height
    for el in [first, *rest]:
        skip, draw = int(el) >> 6, int(el) & 63
        y -= skip
        for _ in range(draw):
            y -= 1
            ys.append(y)
    return ys


def test_round_trip_random_with_mips():
    rng = np.random.default_rng(0)
    vox = _random_voxels(rng, (9, 40, 7), 900)
    rle = V.encode_rle(vox, levels=3)
    _same(V.decode_rle(rle, 0), vox)
    # Mip levels decode to the 2x down-sampled voxels (4.4.7).
    _same(V.decode_rle(rle, 1), V.downsample_voxels(vox))
    _same(V.decode_rle(rle, 2), V.downsample_voxels(V.downsample_voxels(vox)))


def test_column_mips_keep_heights():
    # mips="column": x and z halved per level, y kept; the voxels decode to a 2x1x2
    # down-sampling whose occupancy is the OR of the children, checked against NumPy.
    rng = np.random.default_rng(1)
    vox = _random_voxels(rng, (9, 40, 7), 900)
    rle = V.encode_rle(vox, levels=3, mips="column")
    assert rle.column_mips and rle.level_shapes == ((9, 40, 7), (5, 40, 4), (3, 40, 2))
    _same(V.decode_rle(rle, 0), vox)
    occ = np.zeros(vox.shape, bool)
    occ[tuple(np.asarray(vox.coords).T)] = True
    for level in (1, 2):
        f = 2**level
        want = np.zeros(rle.level_shapes[level], bool)
        c = np.asarray(vox.coords)
        want[c[:, 0] // f, c[:, 1], c[:, 2] // f] = True
        got = V.decode_rle(rle, level)
        have = np.zeros(rle.level_shapes[level], bool)
        have[tuple(np.asarray(got.coords).T)] = True
        np.testing.assert_array_equal(have, want)
    with pytest.raises(ValueError, match="mips"):
        V.encode_rle(vox, levels=2, mips="octree")


def test_long_runs_and_long_skips_split():
    # One column, 3000 high: a 200-voxel run at the top (> 63 drawn), then a
    # gap of 2500 (> 1023 skipped), then a 5-voxel run.
    H = 3000
    ys = list(range(H - 1, H - 201, -1)) + list(range(H - 201 - 2500, H - 201 - 2505, -1))
    coords = np.array([[0, y, 0] for y in ys])
    colors = (np.arange(len(ys))[:, None] * [1, 3, 7] % 256).astype(np.uint8)
    vox = V.make_voxels(coords, colors, (1, H, 1))
    rle = V.encode_rle(vox)
    _same(V.decode_rle(rle), vox)
    els = [int(rle.first[0])] + [int(e) for e in rle.elements[: int(rle.count[0]) - 1]]
    skip = [e >> 6 for e in els]
    draw = [e & 63 for e in els]
    assert max(draw) <= 63 and max(skip) <= 1023
    assert sum(draw) == len(ys)
    assert (1023 in skip) and draw.count(63) == 3  # 200 = 63 + 63 + 63 + 11
    # The slow reference decoder agrees.
    got = _decode_column_numpy(els[0], els[1:], H)
    assert got == sorted(ys, reverse=True)


def test_first_element_inline_and_layout():
    vox = V.make_voxels([[0, 4, 0], [0, 3, 0], [0, 0, 0], [1, 4, 1]], np.zeros((4, 3)), (2, 5, 2))
    rle = V.encode_rle(vox)
    # Column (0, 0): skip 0 draw 2, then skip 2 draw 1 (Fig. 4.11 layout).
    assert int(rle.first[0]) == (0 << 6) | 2
    assert int(rle.count[0]) == 2
    assert int(rle.elements[int(rle.ptr[0])]) == (2 << 6) | 1
    assert int(rle.count[1]) == 0 and int(rle.count[2]) == 0
    assert int(rle.first[3]) == 1 and int(rle.count[3]) == 1


def test_bits_per_voxel_accounting():
    vox = V.make_voxels([[0, 4, 0], [0, 3, 0], [0, 0, 0], [1, 4, 1]], np.zeros((4, 3)), (2, 5, 2))
    st = V.rle_stats(V.encode_rle(vox))
    # 4 pointer-map entries x 64 bits + 1 stored element x 16 bits, over 4 voxels.
    assert st["bits_per_voxel"] == pytest.approx((4 * 64 + 16) / 4)
    assert st["rle_elements"] == 3
    assert st["bytes_with_color"] == (4 * 64 + 16) // 8 + 3 * 4 + 4 * 4


def test_surface_mask_matches_bruteforce():
    rng = np.random.default_rng(1)
    occ = rng.random((6, 5, 7)) < 0.6
    got = V.surface_mask(occ)
    want = np.zeros_like(occ)
    for x, y, z in np.argwhere(occ):
        for d in [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]:
            n = (x + d[0], y + d[1], z + d[2])
            if not all(0 <= n[i] < occ.shape[i] for i in range(3)) or not occ[n]:
                want[x, y, z] = True
    np.testing.assert_array_equal(got, want)
    # The sparse version agrees with the dense one.
    col = np.zeros(occ.shape + (3,), np.uint8)
    dense = V.dense_to_voxels(occ, col)
    sparse = V.surface_voxels(V.dense_to_voxels(occ, col, surface=False))
    _same(dense, sparse)


def test_voxelize_cube_shell_exact():
    # A cube's 12 triangles at resolution 16 give exactly the 16^3 - 14^3 shell.
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )  # fmt: skip
    vox = V.voxelize_mesh(v, f, 16)
    assert vox.shape == (16, 16, 16)
    occ, _ = V.voxels_to_dense(vox)
    want = np.ones((16, 16, 16), bool)
    want[1:-1, 1:-1, 1:-1] = False
    np.testing.assert_array_equal(occ, want)
    # Without vertex colours every voxel has the material colour (clay by default).
    assert np.all(vox.colors == V.CLAY)
    assert np.all(V.voxelize_mesh(v, f, 4, color=(1, 2, 3)).colors == [1, 2, 3])
    # Vertex colours are interpolated.
    vc = np.tile([[200, 10, 10]], (8, 1))
    vox = V.voxelize_mesh(v, f, 8, vertex_colors=vc)
    assert np.all(vox.colors == [200, 10, 10])


def test_voxelize_bad_input():
    v = np.zeros((3, 3))
    f = np.array([[0, 1, 2]])
    with pytest.raises(ValueError, match="resolution"):
        V.voxelize_mesh(v + np.eye(3), f, 0)
    with pytest.raises(ValueError, match="absurdly large"):
        V.voxelize_mesh(v + np.eye(3), f, 10**6)
    with pytest.raises(TypeError, match="resolution"):
        V.voxelize_mesh(v + np.eye(3), f, 4.5)
    with pytest.raises(ValueError, match="zero extent"):
        V.voxelize_mesh(v, f, 8)
    with pytest.raises(ValueError, match="faces"):
        V.voxelize_mesh(v + np.eye(3), np.array([[0, 1, 5]]), 8)


def test_procedural_tree_seeded():
    a = V.procedural_tree(32, key=jax.random.key(3), depth=3)
    b = V.procedural_tree(32, key=jax.random.key(3), depth=3)
    c = V.procedural_tree(32, key=jax.random.key(4), depth=3)
    _same(a, b)
    assert len(a.coords) > 100
    assert not (len(a.coords) == len(c.coords) and np.array_equal(a.coords, c.coords))
    # Surface only: no voxel has all six neighbours set.
    occ, _ = V.voxels_to_dense(a)
    assert np.array_equal(V.surface_mask(occ), occ)
    # Trunk at the bottom centre.
    assert a.coords[:, 1].min() == 0


def test_place_instances_shares_columns():
    rng = np.random.default_rng(2)
    vox = _random_voxels(rng, (4, 10, 6), 60)
    rle = V.encode_rle(vox, levels=2)
    tiles = [[0, 0], [2, 1], [1, 2]]
    scene = V.place_instances(rle, tiles, (3, 3))
    assert scene.elements is rle.elements and scene.colors is rle.colors
    assert scene.count is rle.count  # not even the pointer map is copied
    assert scene.shape == (12, 10, 18)
    got = V.decode_rle(scene)
    want = V.make_voxels(
        np.concatenate([vox.coords + [t[0] * 4, 0, t[1] * 6] for t in tiles]),
        np.concatenate([vox.colors] * 3),
        (12, 10, 18),
    )
    _same(got, want)
    # Memory grows by one 32-bit tile entry per map tile only.
    one, many = (
        V.rle_stats(rle),
        V.rle_stats(V.place_instances(rle, np.argwhere(np.ones((9, 9))), (9, 9))),
    )
    assert many["position_bytes"] - one["position_bytes"] == 81 * 4
    with pytest.raises(ValueError, match="overlaps"):
        V.place_instances(rle, [[0, 0], [0, 0]], (3, 3))
    with pytest.raises(ValueError, match="leaves"):
        V.place_instances(rle, [[3, 0]], (3, 3))
    with pytest.raises(ValueError, match="multiples"):
        V.place_instances(
            V.encode_rle(_random_voxels(rng, (5, 4, 4), 9), levels=2), [[0, 0]], (2, 2)
        )


def test_scene_save_load(tmp_path):
    rng = np.random.default_rng(5)
    vox = _random_voxels(rng, (5, 6, 7), 40)
    V.save_scene(tmp_path / "s.npz", vox)
    _same(V.load_scene(tmp_path / "s.npz"), vox)
    with pytest.raises(ValueError, match="not found"):
        V.load_scene(tmp_path / "missing.npz")


# ---------------------------------------------------------------------------
# Real data
# ---------------------------------------------------------------------------


# The counts are each file's own header field numvoxs (int32 at byte 28) and the shapes
# its xsiz, zsiz, ysiz (int32s at bytes 4, 12, 8; Voxlap's z is our y), as listed in
# ../shared/data/README.md; the test also reads them from the header itself.
@pytest.mark.parametrize(
    "name,count,shape",
    [
        ("caco", 12649, (85, 68, 72)),
        ("barrel", 10788, (52, 60, 52)),
        ("anasplit", 26136, (82, 229, 35)),
    ],
)
def test_kv6_counts(data_dir, name, count, shape):
    path = data_dir / "voxlap" / f"{name}.kv6"
    xs, ys, zs = struct.unpack_from("<iii", path.read_bytes(), 4)
    (numvoxs,) = struct.unpack_from("<i", path.read_bytes(), 28)
    assert numvoxs == count and (xs, zs, ys) == shape
    vox = V.load_kv6(path)
    assert len(vox.coords) == count and vox.shape == shape
    _same(V.decode_rle(V.encode_rle(vox)), vox)


def test_kv6_truncated_and_bad_magic(data_dir, tmp_path):
    raw = (data_dir / "voxlap" / "barrel.kv6").read_bytes()
    p = tmp_path / "t.kv6"
    p.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="truncated"):
        V.load_kv6(p)
    p.write_bytes(b"Kvxx" + raw[4:])
    with pytest.raises(ValueError, match="magic"):
        V.load_kv6(p)


def _vxl_colour_count(data: bytes) -> int:
    """Coloured voxels of a .vxl by Voxlap's own sequential span walk (vxlform.txt).

    A span header is ``[N, S, E, A]``: a span with N > 0 is N words long and holds N - 1
    colours; the last span of a column (N = 0) holds E - S + 1 colours.
    """
    pos, total = 108, 0
    while pos < len(data):
        n, s, e = data[pos], data[pos + 1], data[pos + 2]
        if n == 0:
            total += e - s + 1
            pos += 4 * (e - s + 2)
        else:
            total += n - 1
            pos += 4 * n
    assert pos == len(data)
    return total


def test_vxl_counts_and_round_trip(data_dir):
    path = data_dir / "voxlap" / "untitled.vxl"
    vox = V.load_vxl(path)
    # 1,477,216 top + 375,709 bottom colours in 1,253,394 spans of 1024^2 columns
    # (../shared/data/README.md); recounted here by the plain span walk.
    assert len(vox.coords) == 1_852_925 == _vxl_colour_count(path.read_bytes())
    assert vox.shape == (1024, 256, 1024)
    # Round trip on a crop keeps the test quick.
    crop = V.crop_voxels(vox, (300, 0, 300), (428, 256, 428))
    _same(V.decode_rle(V.encode_rle(crop, levels=2)), crop)


def test_vxl_truncated(data_dir, tmp_path):
    raw = (data_dir / "voxlap" / "untitled.vxl").read_bytes()
    p = tmp_path / "t.vxl"
    p.write_bytes(raw[:200_000])
    with pytest.raises(ValueError, match="truncated|corrupt|columns"):
        V.load_vxl(p)
    p.write_bytes(struct.pack("<I", 0x1234) + raw[4:1000])
    with pytest.raises(ValueError, match="magic"):
        V.load_vxl(p)


def test_volumes_and_errors(data_dir, tmp_path):
    vol, spacing = V.load_volume(data_dir / "volumes" / "HeadMRVolume.mhd")
    assert vol.shape == (48, 62, 42) and vol.dtype == np.uint8
    np.testing.assert_allclose(spacing, [4, 4, 4])
    ct, _ = V.load_volume(data_dir / "volumes" / "headsq" / "quarter.nhdr")
    assert ct.shape == (64, 64, 93) and ct.dtype == np.int16
    vox = V.volume_to_voxels(ct, 1000, up_axis=2)
    assert vox.shape == (64, 93, 64) and len(vox.coords) > 1000
    occ = np.transpose(ct, (0, 2, 1))[:, :, ::-1] >= 1000  # z up: (x, y, z) -> (x, z, -y)
    np.testing.assert_array_equal(V.voxels_to_dense(vox)[0], V.surface_mask(occ))
    with pytest.raises(ValueError, match="iso"):
        V.volume_to_voxels(vol, 300)
    with pytest.raises(ValueError, match="iso"):
        V.volume_to_voxels(vol, 0)
    # A raw file of the wrong size for its header.
    (tmp_path / "v.raw").write_bytes(b"\0" * 100)
    (tmp_path / "v.mhd").write_text(
        "NDims = 3\nDimSize = 4 4 4\nElementType = MET_UCHAR\nElementDataFile = v.raw\n"
    )
    with pytest.raises(ValueError, match="bytes"):
        V.load_volume(tmp_path / "v.mhd")
    with pytest.raises(ValueError, match="extension"):
        V.load_volume(tmp_path / "v.raw")


@pytest.mark.parametrize("up", ["x", "y", "z", "-x", "-y", "-z"])
def test_turn_up_is_a_rotation(up):
    from jaxgfx._src.voxel.volume import turn_up
    from jaxgfx.io import up_rotation

    shape = (2, 3, 4)
    src = np.stack(np.meshgrid(*map(np.arange, shape), indexing="ij"), -1)  # own index
    out = turn_up(src, up)
    # The source index is an affine map of the world index: A = d source / d world.
    a = np.stack([out[tuple(np.eye(3, dtype=int)[w])] - out[0, 0, 0] for w in range(3)], 1)
    assert sorted(np.abs(a).sum(0)) == [1, 1, 1] and round(np.linalg.det(a)) == 1  # no mirror
    axis = "xyz".index(up[-1])
    assert a[axis, 1] == (-1 if up.startswith("-") else 1)  # world +y walks along +/- up
    if len(up) == 1:  # the same turn as meshes get (jaxgfx.io.up_rotation, world = R src)
        np.testing.assert_array_equal(a, up_rotation(up).T)
    with pytest.raises(ValueError, match="up_axis"):
        turn_up(src, "w")


def _sphere(shape, spacing, radius):
    """uint8 volume: 200 inside a sphere of ``radius`` (physical units) about the centre, 10 out."""
    axes = [(np.arange(n) + 0.5) * s for n, s in zip(shape, spacing)]
    grid = np.meshgrid(*axes, indexing="ij")
    centre = np.asarray(shape) * np.asarray(spacing) / 2
    r = np.sqrt(sum((g - c) ** 2 for g, c in zip(grid, centre)))
    return np.where(r < radius, 200, 10).astype(np.uint8)


def _write_raw(tmp_path, vol, name="v.raw"):
    (tmp_path / name).write_bytes(np.ascontiguousarray(vol.transpose(2, 1, 0)).tobytes())


def _extent(vox):
    c = np.asarray(vox.coords)
    return c.max(0) - c.min(0) + 1


def test_volume_spacing_kept(tmp_path):
    # A ball sampled at spacing (1, 1, 2): 16 x 16 x 8 samples, 16 units each way.
    vol = _sphere((16, 16, 8), (1, 1, 2), 6.0)
    _write_raw(tmp_path, vol)
    (tmp_path / "v.mhd").write_text(
        "NDims = 3\nDimSize = 16 16 8\nElementSpacing = 1 1 2\nElementType = MET_UCHAR\n"
        "ElementDataFile = v.raw\n"
    )
    (tmp_path / "v.nhdr").write_text(
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 16 16 8\nencoding: raw\n"
        "space directions: (1,0,0) (0,1,0) (0,0,2)\ndata file: v.raw\n"
    )
    for name in ("v.mhd", "v.nhdr"):
        got, spacing = V.load_volume(tmp_path / name)
        np.testing.assert_array_equal(got, vol)
        np.testing.assert_allclose(spacing, [1, 1, 2])
        vox = V.volume_to_voxels(got, spacing=spacing, up_axis=2)  # iso: Otsu
        assert vox.shape == (16, 16, 16)
        ext = _extent(vox)
        assert ext.max() - ext.min() <= 1 and ext.min() >= 10, ext  # a ball, not an egg
    flat = _extent(V.volume_to_voxels(vol, up_axis=2))  # the spacing dropped: half as tall
    assert abs(flat[1] * 2 - flat[0]) <= 2
    assert (
        V.volume_to_voxels(vol, 100, spacing=(1, 1, 2), resolution=8, up_axis=2).shape == (8,) * 3
    )
    with pytest.raises(ValueError, match="spacing"):
        V.volume_to_voxels(vol, 100, spacing=(1, 0, 2))


def test_resample_isotropic_is_exact_for_linear_data():
    spacing = np.array([1.0, 2.0, 3.0])
    shape = (6, 5, 4)
    x, y, z = np.meshgrid(*[(np.arange(n) + 0.5) * s for n, s in zip(shape, spacing)],
                          indexing="ij")  # fmt: skip
    out = V.resample_isotropic(2 * x + 3 * y + 5 * z, spacing)
    assert out.shape == V.isotropic_shape(shape, spacing) == (6, 10, 12)
    X, Y, Z = np.meshgrid(*[np.arange(n) + 0.5 for n in out.shape], indexing="ij")
    # Inside the outermost sample centres the interpolation reproduces the plane.
    inside = (Y >= 1) & (Y <= 9) & (Z >= 1.5) & (Z <= 10.5)
    np.testing.assert_allclose(out[inside], (2 * X + 3 * Y + 5 * Z)[inside], atol=1e-4)


def test_otsu_matches_brute_force():
    rng = np.random.default_rng(0)
    v = np.concatenate([rng.normal(50, 6, 3000), rng.normal(170, 12, 1000)])
    v = np.clip(np.round(v), 0, 255).astype(np.uint8)

    def between(t):
        hi = v >= t
        w = hi.mean()
        return w * (1 - w) * (v[hi].mean() - v[~hi].mean()) ** 2

    best = max(range(int(v.min()) + 1, int(v.max()) + 1), key=between)
    t = V.otsu_threshold(v)
    assert v.min() < t <= v.max()
    assert between(t) >= between(best) * (1 - 1e-9)  # same split (integer data, <1-wide bins)
    with pytest.raises(ValueError, match="constant"):
        V.otsu_threshold(np.ones(5))


def _vtk_header(mode, dims, spacing_line, kind="short"):
    return (
        "# vtk DataFile Version 3.0\ntest volume\n\n" + mode + "\n\nDATASET STRUCTURED_POINTS\n"
        f"DIMENSIONS {dims[0]} {dims[1]} {dims[2]}\n{spacing_line}\nORIGIN 0 0 0\n"
        f"POINT_DATA {int(np.prod(dims))}\nSCALARS density {kind} 1\nLOOKUP_TABLE default\n"
    ).encode()


def test_vtk_structured_points(tmp_path):
    rng = np.random.default_rng(1)
    vol = rng.integers(-300, 3000, (5, 4, 3)).astype(np.int16)
    flat = vol.transpose(2, 1, 0).ravel()  # x varies fastest
    p = tmp_path / "b.vtk"
    p.write_bytes(
        _vtk_header("BINARY", vol.shape, "SPACING 0.5 0.5 2") + flat.astype(">i2").tobytes()
    )
    got, spacing = V.load_volume(p)
    np.testing.assert_array_equal(got, vol)
    np.testing.assert_allclose(spacing, [0.5, 0.5, 2])
    q = tmp_path / "a.vtk"
    q.write_bytes(
        _vtk_header("ASCII", vol.shape, "ASPECT_RATIO 1 2 3") + " ".join(map(str, flat)).encode()
    )
    got, spacing = V.load_volume(q)
    np.testing.assert_array_equal(got, vol)
    np.testing.assert_allclose(spacing, [1, 2, 3])
    p.write_bytes(p.read_bytes()[:-7])
    with pytest.raises(ValueError, match="truncated"):
        V.load_volume(p)
    p.write_bytes(b"# vtk DataFile Version 3.0\nmesh\nASCII\nDATASET POLYDATA\nPOINTS 0 float\n")
    with pytest.raises(ValueError, match="STRUCTURED_POINTS"):
        V.load_volume(p)
    # Other formats go through SimpleITK (optional): either it is missing (the error
    # names the extra) or it cannot read this junk.
    (tmp_path / "x.nii").write_bytes(b"junk")
    with pytest.raises(ValueError, match="SimpleITK"):
        V.load_volume(tmp_path / "x.nii")


def test_simpleitk_formats(tmp_path):
    sitk = pytest.importorskip("SimpleITK", reason="the optional extra jaxgfx[volumes]")
    vol = np.arange(5 * 4 * 3, dtype=np.int16).reshape(5, 4, 3)
    image = sitk.GetImageFromArray(vol.transpose(2, 1, 0))  # SimpleITK arrays are (z, y, x)
    image.SetSpacing((0.5, 1.0, 2.0))
    for name in ("v.nii.gz", "v.mha", "v.nrrd"):  # .nrrd: attached data, read by SimpleITK
        sitk.WriteImage(image, str(tmp_path / name))
        got, spacing = V.load_volume(tmp_path / name)
        np.testing.assert_array_equal(got, vol)
        np.testing.assert_allclose(spacing, [0.5, 1.0, 2.0])


def test_iron_protein_loads(data_dir, tmp_path):
    vol, spacing = V.load_volume(data_dir / "volumes" / "ironProt.vtk")
    assert vol.shape == (68, 68, 68) and vol.dtype == np.uint8
    np.testing.assert_allclose(spacing, [1, 1, 1])
    vox = V.volume_to_voxels(vol, spacing=spacing, up_axis=2)
    assert vox.shape == (68, 68, 68) and len(vox.coords) > 1000
    # Through the command line, without --resolution.
    from jaxgfx.cli import main

    out = tmp_path / "iron.npz"
    assert main(["voxelize", str(data_dir / "volumes" / "ironProt.vtk"), "--out", str(out)]) == 0
    assert V.load_scene(out).shape == (68, 68, 68)


def test_cli_volumes(tmp_path, capsys):
    import json

    from jaxgfx.cli import main

    vol = _sphere((16, 16, 8), (1, 1, 2), 6.0)
    vol[:3, :3, :2] = 200  # a corner block: the turns below are told apart
    _write_raw(tmp_path, vol)
    hdr = tmp_path / "v.mhd"
    hdr.write_text(
        "NDims = 3\nDimSize = 16 16 8\nElementSpacing = 1 1 2\nElementType = MET_UCHAR\n"
        "ElementDataFile = v.raw\n"
    )
    out = tmp_path / "v.npz"
    assert main(["voxelize", str(hdr), "--out", str(out)]) == 0
    vox = V.load_scene(out)
    assert vox.shape == (16, 16, 16)
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["spacing"] == [1, 1, 2] and 10 < line["iso"] <= 200  # Otsu, between the values
    # --up=-z turns the scan the other way round about x (y and z reversed), and then half
    # round about y so that its front (-y, as in DICOM / NRRD patient coordinates) faces +z.
    assert main(["voxelize", str(hdr), "--up=-z", "--out", str(tmp_path / "down.npz")]) == 0
    down = V.voxels_to_dense(V.load_scene(tmp_path / "down.npz"))[0]
    np.testing.assert_array_equal(down, V.voxels_to_dense(vox)[0][::-1, ::-1, :])
    assert not np.array_equal(down, V.voxels_to_dense(vox)[0])
    assert main(["voxelize", str(hdr), "--resolution", "8", "--out", str(out)]) == 0
    assert V.load_scene(out).shape == (8, 8, 8)
    capsys.readouterr()
    assert main(["voxelize", str(hdr), "--iso", "1000", "--out", str(out)]) == 2
    assert "error: --iso 1000" in capsys.readouterr().err
    assert main(["voxelize", str(tmp_path / "v.vtk"), "--out", str(out)]) == 2
    assert "not found" in capsys.readouterr().err
    # A spacing so uneven that cubic voxels would not fit: refused before resampling.
    (tmp_path / "thin.mhd").write_text(
        "NDims = 3\nDimSize = 16 16 8\nElementSpacing = 1 1 1e-5\nElementType = MET_UCHAR\n"
        "ElementDataFile = v.raw\n"
    )
    assert main(["voxelize", str(tmp_path / "thin.mhd"), "--out", str(out)]) == 2
    assert "pass --resolution N for fewer" in capsys.readouterr().err
    assert main(["voxelize", "tree", "--resolution", "8", "--up", "z", "--out", str(out)]) == 2
    assert "error: --up applies to meshes and volumes" in capsys.readouterr().err
    assert main(["voxelize", "m.ply", "--resolution", "8", "--up=-z", "--out", str(out)]) == 2
    assert "error: --up -z: meshes take x, y or z" in capsys.readouterr().err


def test_cli_voxelize_and_render(tmp_path, capsys):
    import json

    import imageio.v3 as iio

    from jaxgfx.cli import main

    scene = tmp_path / "tree.npz"
    assert main(["voxelize", "tree", "--resolution", "16", "--out", str(scene)]) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    vox = V.load_scene(scene)
    assert line["voxels"] == len(vox.coords) > 0
    assert line["bits_per_voxel"] > 0
    png, dep = tmp_path / "f.png", tmp_path / "d.npy"
    # No --camera: the default frames the scene; lit by default, --unlit gives albedo.
    argv = ["render-voxels", str(scene), "--fov", "60",
            "--size", "24x16", "--out", str(png), "--depth", str(dep)]  # fmt: skip
    assert main(argv + ["--unlit"]) == 0
    unlit = iio.imread(png)
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["lit"] is False and len(line["camera"].split(",")) == 5
    assert main(argv) == 0
    assert "warning" not in capsys.readouterr().err
    lit = iio.imread(png)
    depth = np.load(dep)
    # (The reference DDA hits 8.3 % of this small frame; render_rle 8.6 %.)
    assert (
        depth.shape == (16, 24) and np.isfinite(depth).mean() > 0.06 and not np.isnan(depth).any()
    )
    hit = np.isfinite(depth)
    # both on the sky of every other pass (blue above, not black); only the voxels are lit
    assert np.array_equal(lit[~hit], unlit[~hit]) and lit[~hit][:, 2].min() > 100
    assert np.abs(lit[hit].astype(int) - unlit[hit]).mean() > 5
    # The wide traversal (a map beyond the scatter's limits) with a one-entry list per
    # plane: the lost elements are counted and told on stderr with a --buffer-size
    # that fits, and that size gives the default traversal's frame back.
    wide = argv + ["--traversal", "wide"]
    assert main(wide + ["--buffer-size", "1"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out.strip().splitlines()[-1])["buffer_overflow"] > 0
    fits = cap.err.split("--buffer-size ")[1].split()[0]
    assert main(wide + ["--buffer-size", fits]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out.strip().splitlines()[-1])["buffer_overflow"] == 0
    assert "warning" not in cap.err and np.array_equal(np.load(dep), depth)
    # 2x1 AA: the same view on pixels half as wide, averaged back to --size.
    assert main(argv + ["--aa", "2x1", "--reference", "--unlit"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["aa"] == "2x1"
    d_aa = np.load(dep)
    assert d_aa.shape == (16, 24)
    # Same view: the hits overlap the 1x1 frame's and lie at the same depth.
    hits, hits_aa = np.isfinite(depth), np.isfinite(d_aa)
    both = hits & hits_aa
    assert hits.sum() > 5 and both.sum() >= 0.7 * hits.sum() and hits_aa.sum() <= 2 * hits.sum()
    assert np.median(np.abs(d_aa[both] - depth[both])) < 1.0
    assert main(argv + ["--aa", "3x1"]) == 2
    assert "error: argument --aa" in capsys.readouterr().err
    # Resolution is for meshes and trees only; it must be positive.
    assert main(["voxelize", "x.kv6", "--resolution", "8", "--out", "o.npz"]) == 2
    assert "error: --resolution applies to meshes" in capsys.readouterr().err
    assert main(["voxelize", "tree", "--resolution", "0", "--out", "o.npz"]) == 2
    assert "error: argument --resolution" in capsys.readouterr().err
    # A camera inside solid voxels is refused before rendering.
    solid = V.dense_to_voxels(np.ones((4, 4, 4), bool), np.full((4, 4, 4, 3), 7, np.uint8))
    V.save_scene(tmp_path / "solid.npz", solid)
    argv = ["render-voxels", str(tmp_path / "solid.npz"), "--camera", "0.5,3.5,2.5,0,0",
            "--size", "8x8", "--out", str(png)]  # fmt: skip
    assert main(argv) == 2
    assert "inside a solid voxel" in capsys.readouterr().err


def test_share_columns_stores_copies_once():
    rng = np.random.default_rng(5)
    obj = _random_voxels(rng, (4, 6, 4), 40)
    # Three copies at different heights and positions (no common tile grid or base).
    offs = [(0, 0, 0), (6, 4, 2), (10, 8, 6)]  # even: the mip levels match too
    vox = V.make_voxels(
        np.concatenate([obj.coords + o for o in offs]),
        np.concatenate([obj.colors] * 3),
        (14, 14, 11),
    )
    rle = V.encode_rle(vox, levels=2)
    shared = V.share_columns(rle)
    for level in range(2):
        _same(V.decode_rle(shared, level), V.decode_rle(rle, level))
    a, b = V.rle_stats(rle), V.rle_stats(shared)
    assert b["rle_elements"] == a["rle_elements"]  # the same columns ...
    assert len(shared.colors) < 0.5 * len(rle.colors)  # ... stored once
    assert b["bytes_with_color"] < a["bytes_with_color"]
    np.testing.assert_array_equal(shared.first, rle.first)


def _column_table_numpy(rle, E):
    """Slow reference: (n, top, bottom, valid, drawn before), (C, E) each, element by element."""
    first, count, ptr = (np.asarray(a, np.int64) for a in (rle.first, rle.count, rle.ptr))
    elements = np.asarray(rle.elements, np.int64)
    out = np.zeros((5, len(count), E), np.int64)
    for lev, (_, Y, _) in enumerate(rle.level_shapes):
        stop = rle.level_offsets[lev + 1] if lev + 1 < rle.levels else len(count)
        for c in range(rle.level_offsets[lev], stop):
            y, before = Y, 0
            els = [first[c], *elements[ptr[c] : ptr[c] + count[c] - 1]]
            for j, el in enumerate(els[: int(count[c])]):
                skip, draw = int(el) >> 6, int(el) & 63
                top = y - skip - 1
                out[:, c, j] = count[c], top, top - draw + 1, draw > 0, before
                y, before = y - skip - draw, before + draw
            out[0, c] = count[c]
    return out


def test_tail_sums_read_columns_as_the_decoder():
    """The direct element reads (``tail_sums``) equal a slow element-by-element decode."""
    from jaxgfx._src.voxel import grid

    rng = np.random.default_rng(7)
    obj = _random_voxels(rng, (6, 90, 6), 500)
    # A long column too: runs over 63 drawn and gaps over 1023 skipped split.
    ys = np.r_[np.arange(2999, 2799, -1), np.arange(298, 293, -1)]
    tall = V.make_voxels(np.stack([0 * ys, ys, 0 * ys], 1), np.zeros((len(ys), 3)), (2, 3000, 2))
    for rle in (V.encode_rle(obj, levels=2), V.share_columns(V.encode_rle(obj, levels=2)),
                V.encode_rle(tall)):  # fmt: skip
        E = rle.max_elements
        ref = _column_table_numpy(rle, E)
        rle = V.as_jax(rle)
        cols = np.arange(len(rle.count))
        heights = np.repeat([s[1] for s in rle.level_shapes],
                            np.diff(np.r_[rle.level_offsets, len(cols)]))  # fmt: skip
        j = np.arange(E)

        def both(col, h, rle=rle, E=E, j=j):
            every = grid._column_elements(rle, col, True, h, E)
            safe, n2, d0, b0 = grid._column_head(rle, col, True, h)
            got = grid._column_runs(rle, safe, n2, d0, b0, j)
            bottoms = grid._element_bottoms(rle, safe, b0, j)[0]
            return every, (n2, *got, bottoms)

        every, got = jax.vmap(both)(cols, heights)
        valid = ref[3].astype(bool)
        assert valid.sum() >= 5
        np.testing.assert_array_equal(got[0], ref[0][:, 0])
        np.testing.assert_array_equal(got[3], valid)
        np.testing.assert_array_equal(every[3], valid)
        # top, bottom, drawn before; the bottoms the step counts m from; all of a column
        for a, b in zip(got[1:3] + got[4:] + every[1:3] + every[4:],
                        (*ref[1:3], ref[4], ref[2], *ref[1:3], ref[4])):  # fmt: skip
            np.testing.assert_array_equal(np.asarray(a)[valid], np.asarray(b)[valid])
    # The re-walk's voxel reads give every voxel of the dense grid: solid where it
    # is, with its colour (the tall column: its runs, its gap, above and below it).
    from jaxgfx._src.voxel.warp import _voxel_lookup

    for vox in (obj, tall):
        occ, col = V.voxels_to_dense(vox)
        rle = V.as_jax(V.encode_rle(vox))
        xyz = np.argwhere(np.ones(occ.shape, bool)) if vox is obj else np.argwhere(occ)
        xyz = np.concatenate([xyz, [[0, 2999, 0], [0, 299, 0], [1, 5, 1], [0, -1, 0]]])
        look = jax.jit(jax.vmap(lambda p, r=rle: _voxel_lookup(r, p[0], p[1], p[2])))
        solid, cidx = (np.asarray(a) for a in look(xyz.astype(np.int32)))
        inside = (xyz >= 0).all(1) & (xyz < occ.shape).all(1)
        want = np.zeros(len(xyz), bool)
        want[inside] = occ[tuple(xyz[inside].T)]
        np.testing.assert_array_equal(solid, want)
        colors = np.asarray(rle.colors)[cidx[solid]]
        np.testing.assert_array_equal(colors, col[tuple(xyz[solid].T)])


def test_coverage_test_leaves_out_exactly_the_pairs_behind_every_block_they_reach():
    """A pair is left out only where every texel it reaches holds a nearer writer,
    and always where every block of texels it touches does, whatever its height."""
    from jaxgfx._src.voxel.scatter import _CULL_BLOCK, _NO_KEY, _hidden

    rng = np.random.default_rng(3)
    rows = 12 * _CULL_BLOCK
    T = 50 * _CULL_BLOCK + 7  # a last, partial block
    table = rng.integers(0, 1000, T).astype(np.int32)
    # Texels no writer reached yet, some in runs so that tall pairs can pass.
    table[rng.random(T) < 0.002] = _NO_KEY
    table[7 * _CULL_BLOCK + 3] = _NO_KEY
    n = rng.integers(0, rows + 1, 4000).astype(np.int32)
    n[:2000] = rng.integers(0, 2 * _CULL_BLOCK + 3, 2000)
    t0 = rng.integers(0, T - n + 1).astype(np.int32)
    key = rng.integers(0, 1200, 4000).astype(np.int32)
    hidden = np.asarray(jax.jit(functools.partial(_hidden, rows=rows))(table, n, key, t0))
    nearer = np.array([np.all(table[a : a + m] < k) for a, m, k in zip(t0, n, key)])
    # Blocks as the test reads them: the last one padded with texels no one drew.
    padded = np.pad(table, (0, -T % _CULL_BLOCK), constant_values=_NO_KEY)
    lo, hi = t0 // _CULL_BLOCK, (t0 + np.maximum(n, 1) - 1) // _CULL_BLOCK
    blocks = np.array(
        [
            np.all(padded[a * _CULL_BLOCK : (b + 1) * _CULL_BLOCK] < k)
            for a, b, k in zip(lo, hi, key)
        ]
    )
    drawn = n > 0
    assert not np.any(hidden & ~nearer & drawn)
    np.testing.assert_array_equal(hidden[drawn], blocks[drawn])
    tall = drawn & (hi - lo >= 3)
    assert np.sum(hidden & tall) > 20 and np.sum(hidden & drawn) > 200


def test_plane_rank_is_searchsorted_over_the_live_planes():
    """The bucketed search gives ``searchsorted``'s ranks on either side, for
    crowded buckets, repeated angles, planes without rows and queries outside
    the planes' range."""
    from jaxgfx._src.voxel.scatter_planes import _plane_buckets, _plane_rank

    rng = np.random.default_rng(5)
    # Dense near one angle (many planes a bucket), repeats, sparse elsewhere.
    live = np.sort(
        np.concatenate(
            [rng.uniform(-1.5, 1.9, 300), 0.3 + 1e-4 * rng.random(200), np.full(7, -0.25)]
        )
    ).astype(np.float32)
    angle = np.concatenate([live, np.full(93, np.inf, np.float32)])
    q = np.concatenate(
        [
            rng.uniform(-2.0, 2.0, 3000),
            live[rng.integers(0, live.size, 500)],
            [-2.0, 2.0, live[0], live[-1], np.inf, -np.inf, 0.3],
        ]
    ).astype(np.float32)

    @jax.jit
    def ranks(angle, n_live, q):
        bucket, frame, steps = _plane_buckets(angle, n_live)
        pl = types.SimpleNamespace(
            angle=angle, n_live=n_live, bucket=bucket, bucket_frame=frame, bucket_steps=steps
        )
        right = np.array([False, True])[:, None]
        return _plane_rank(pl, jax.numpy.stack([q, q]), right), steps

    got, steps = ranks(angle, np.int32(live.size), q)
    np.testing.assert_array_equal(np.asarray(got[0]), np.searchsorted(live, q, "left"))
    np.testing.assert_array_equal(np.asarray(got[1]), np.searchsorted(live, q, "right"))
    assert 4 <= int(steps) < 10, int(steps)  # the crowded bucket, not log2 of all planes
    none = ranks(np.full(600, np.inf, np.float32), np.int32(0), q)[0]
    assert not np.any(np.asarray(none))


def test_draw_order_takes_every_element_once_near_columns_first():
    from jaxgfx._src.voxel.scatter_planes import _draw_order

    rle = V.as_jax(V.encode_rle(_random_voxels(np.random.default_rng(4), (6, 9, 5), 60), levels=2))
    C = rle.count.shape[0]
    n = C + int(rle.elements.shape[0])
    X, _, Z = rle.level_shapes[0]
    for eye in ([-40.0, 3.0, 2.0], [3.0, 3.0, 60.0], [9.0, 3.0, -1.0], [2.0, 3.0, -30.0]):
        cam = look_at(eye, [3.0, 4.0, 2.5], 50.0, 16, 12)
        order = np.asarray(_draw_order(rle, cam, n))
        np.testing.assert_array_equal(np.sort(order), np.arange(n))
        assert np.all(order[:C] < C)  # the column heads first
        # The first is a column on the eye's side, across the axis it stands out on.
        ix, iz = divmod(int(order[0]), Z)
        dx, dz = eye[0] - X / 2, eye[2] - Z / 2
        if abs(dx) >= abs(dz):
            assert ix == (0 if dx < 0 else X - 1), eye
        else:
            assert iz == (0 if dz < 0 else Z - 1), eye
