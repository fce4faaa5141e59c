"""UV textures: the pyramid, bilinear and trilinear lookups against float64 NumPy, gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxgfx.raster import mip_pyramid, rasterize, sample_bilinear, texture, uv_footprint

RNG = np.random.default_rng(0)
IMAGE = RNG.uniform(0, 1, (12, 10, 3)).astype(np.float32)


def _numpy_bilinear(image, uv, wrap="repeat"):
    """Texel centres at (i + 0.5) / W: the four around each point, weighted, in float64."""
    h, w = image.shape[:2]
    out = np.zeros(uv.shape[:-1] + image.shape[-1:])
    for idx in np.ndindex(uv.shape[:-1]):
        x, y = uv[idx][0] * w - 0.5, uv[idx][1] * h - 0.5
        i0, j0 = int(np.floor(x)), int(np.floor(y))
        for di, dj in ((0, 0), (1, 0), (0, 1), (1, 1)):
            wx = (x - i0) if di else 1 - (x - i0)
            wy = (y - j0) if dj else 1 - (y - j0)
            i, j = i0 + di, j0 + dj
            i, j = (
                (i % w, j % h)
                if wrap == "repeat"
                else (min(max(i, 0), w - 1), min(max(j, 0), h - 1))
            )
            out[idx] += wx * wy * image[j, i]
    return out


def test_the_pyramid_is_box_filtered_down_to_one_texel():
    tex = mip_pyramid(IMAGE)
    assert tex.sizes == ((12, 10), (6, 5), (3, 3), (2, 2), (1, 1))
    np.testing.assert_allclose(tex.level(1), IMAGE.reshape(6, 2, 5, 2, 3).mean((1, 3)), atol=1e-6)
    # an odd side keeps its last row whole: the 3 x 3 level's last column is the 6 x 5
    # level's last column averaged over row pairs
    one = np.asarray(tex.level(1), np.float64)
    np.testing.assert_allclose(tex.level(2)[:, 2], one[:, 4].reshape(3, 2, 3).mean(1), atol=1e-6)
    np.testing.assert_allclose(tex.level(4)[0, 0], np.asarray(tex.level(3)).mean((0, 1)), atol=1e-6)
    assert mip_pyramid((IMAGE * 255).astype(np.uint8)).texels.dtype == jnp.float32
    with pytest.raises(ValueError, match="image must have shape"):
        mip_pyramid(np.zeros((4,)))


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_bilinear_lookups_are_numpys(wrap):
    tex = mip_pyramid(IMAGE, levels=2)
    uv = RNG.uniform(-0.3, 1.3, (40, 2))
    got = np.asarray(sample_bilinear(tex, uv, wrap=wrap))
    np.testing.assert_allclose(got, _numpy_bilinear(IMAGE.astype(np.float64), uv, wrap), atol=2e-6)
    level1 = np.asarray(tex.level(1), np.float64)
    got1 = np.asarray(sample_bilinear(tex, uv, level=1, wrap=wrap))
    np.testing.assert_allclose(got1, _numpy_bilinear(level1, uv, wrap), atol=2e-6)
    # texel centres read back the texels
    j, i = np.meshgrid(np.arange(12), np.arange(10), indexing="ij")
    centres = np.stack([(i + 0.5) / 10, (j + 0.5) / 12], -1)
    np.testing.assert_allclose(np.asarray(texture(tex, centres, wrap=wrap)), IMAGE, atol=1e-6)
    with pytest.raises(ValueError, match="wrap"):
        texture(tex, uv, wrap="mirror")


def test_trilinear_blends_the_two_levels_the_footprint_brackets():
    tex = mip_pyramid(IMAGE)
    uv = RNG.uniform(0, 1, (30, 2))
    image64 = IMAGE.astype(np.float64)
    levels = [np.asarray(tex.level(k), np.float64) for k in range(len(tex.sizes))]
    # a footprint of 2.83 level-0 texels: lod 1.5, half level 1 and half level 2
    fp = np.full((30, 2), 2**1.5 / 12)
    want = 0.5 * _numpy_bilinear(levels[1], uv) + 0.5 * _numpy_bilinear(levels[2], uv)
    np.testing.assert_allclose(np.asarray(texture(tex, uv, fp)), want, atol=2e-6)
    # magnified (less than a texel a pixel) is level 0; far beyond the pyramid its top
    np.testing.assert_allclose(
        np.asarray(texture(tex, uv, fp / 100)), _numpy_bilinear(image64, uv), atol=2e-6
    )
    np.testing.assert_allclose(
        np.asarray(texture(tex, uv, fp * 1e4)),
        np.broadcast_to(levels[-1][0, 0], (30, 3)),
        atol=2e-6,
    )


def test_texture_gradients_match_finite_differences():
    tex = mip_pyramid(IMAGE)
    # Halfway between texel centres of levels 0 and 1 (the footprint blends those two), give
    # or take a fifth of a texel: no finite-difference step crosses a centre, where the
    # bilinear lookups have kinks.
    m, n = np.meshgrid(np.arange(4), np.arange(4))
    uv = np.stack([(m.ravel() + 1) / 5, (n.ravel() + 1) / 6], -1) + RNG.uniform(
        -0.02, 0.02, (16, 2)
    )
    uv = uv.astype(np.float32)
    fp = np.full((16, 2), 0.12, np.float32)
    weights = RNG.uniform(size=(16, 3)).astype(np.float32)

    @jax.jit
    def loss(texels, uv):
        t = type(tex)(texels, tex.sizes)
        return jnp.sum(texture(t, uv, fp) * weights)

    # float64 for the finite differences: texels stay float64, UVs are read in float32 (the
    # lookups' precision), so their steps are large (1e-3 of the texture).
    with jax.enable_x64(True):
        texels = jnp.asarray(tex.texels, jnp.float64)
        uv64 = jnp.asarray(uv, jnp.float64)
        check_grads(lambda t: loss(t, uv64), (texels,), order=1, modes=("rev",), eps=1e-4)
        check_grads(
            lambda u: loss(texels, u), (uv64,), order=1, modes=("rev",), eps=1e-3, rtol=2e-3
        )
    # through the pyramid to the base image
    g = jax.grad(lambda img: jnp.sum(texture(mip_pyramid(img), uv, fp) * weights))(IMAGE)
    assert g.shape == IMAGE.shape and np.abs(np.asarray(g)).sum() > 0


def test_a_rasterized_checkerboard_reads_its_texels():
    # A square facing the camera, UVs at its corners: each pixel's colour is the texture at
    # the pixel centre's UV, which here is a linear function of the pixel (a closed form).
    from jaxgfx.camera import camera_from_degrees

    cam = camera_from_degrees([0.0, 0.0, -2.0], fov=60.0, width=32, height=24)
    v = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    checker = (np.indices((8, 8)).sum(0) % 2).astype(np.float32)[..., None] * [1.0, 0.5, 0.2]
    tex = mip_pyramid(checker)
    out = rasterize(cam, v, f, uv)
    fp = uv_footprint(out.color, out.tri_id)
    rgb = np.asarray(texture(tex, out.color, fp))
    hit = np.asarray(out.tri_id) >= 0
    # world x at the pixel centre, on the plane z = 0 seen from z = -2 (x flipped: +x is left)
    fy = 12 / np.tan(np.radians(30))
    px = (np.arange(32) + 0.5 - 16) / fy * 2
    py = (12 - (np.arange(24) + 0.5)) / fy * 2
    u_ref = np.broadcast_to((1 - px[None, :]) / 2, (24, 32))
    v_ref = np.broadcast_to((1 - py[:, None]) / 2, (24, 32))
    uv_ref = np.stack([u_ref, v_ref], -1)
    np.testing.assert_allclose(np.asarray(out.color)[hit], uv_ref[hit], atol=1e-5)
    # 8 texels over ~20 pixels: magnified, level 0, bilinear
    np.testing.assert_allclose(np.asarray(fp)[hit].max(), 1 / 20.8, rtol=0.05)
    want = _numpy_bilinear(checker.astype(np.float64), uv_ref[hit][None])[0]
    np.testing.assert_allclose(rgb[hit], want, atol=1e-4)


def _textured_box(path):
    """A unit box with a 2 x 2 colour texture (red, green / blue, white), saved by trimesh."""
    import trimesh
    from PIL import Image

    box = trimesh.creation.box((2.0, 2.0, 2.0))
    # UVs from the vertices' x and y: every face shows part of the 2 x 2 pattern
    v = np.asarray(box.vertices)
    uv = np.stack([(v[:, 0] + 1) / 2, (v[:, 1] + 1) / 2], -1)
    pixels = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], np.uint8)
    box.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(pixels))
    box.export(path)
    return pixels


def test_gltf_and_obj_textures_are_read_top_left_first(tmp_path):
    from jaxgfx.io import load_mesh, mesh_texture
    from jaxgfx.skin import load_gltf_meshes

    pixels = _textured_box(tmp_path / "box.glb")
    (mesh,) = load_gltf_meshes(tmp_path / "box.glb")
    assert mesh.texture is not None and mesh.uvs is not None
    np.testing.assert_array_equal(mesh.texture[..., :3], pixels)
    # the vertex at x = -1, y = +1 has uv (0, 1) in trimesh's (OBJ's) convention: v up, so
    # glTF's top-left-first v is 0 there: the red texel
    top_left = np.argmin(mesh.vertices[:, 0] - mesh.vertices[:, 1])
    np.testing.assert_allclose(mesh.uvs[top_left], [0.0, 0.0], atol=1e-6)
    _textured_box(tmp_path / "box.obj")
    obj = load_mesh(tmp_path / "box.obj")
    uvs, image = mesh_texture(obj)
    assert image is not None and uvs is not None
    np.testing.assert_array_equal(image[..., :3], pixels)
    k = np.argmin(np.asarray(obj.vertices)[:, 0] - np.asarray(obj.vertices)[:, 1])
    np.testing.assert_allclose(uvs[k], [0.0, 0.0], atol=1e-6)


def test_render_draws_a_glb_with_its_texture(tmp_path):
    import imageio.v3 as iio

    from jaxgfx.cli import main

    _textured_box(tmp_path / "box.glb")
    png = tmp_path / "box.png"
    assert main(["render", str(tmp_path / "box.glb"), "--size", "32x24", "--out", str(png)]) == 0
    img = np.asarray(iio.imread(png))[..., :3].astype(int)
    # the front face shows the texture's colours: red-, green-, blue-dominant pixels all occur
    others = [img[..., [1, 2]].max(-1), img[..., [0, 2]].max(-1), img[..., [0, 1]].max(-1)]
    dominant = [img[..., c] > 1.6 * others[c] for c in range(3)]
    assert all(d.sum() > 4 for d in dominant), [int(d.sum()) for d in dominant]


def test_bad_texture_input_is_refused_naming_the_argument():
    import jaxgfx
    from jaxgfx.scene import merge_mesh_passes, mesh_pass

    tex = mip_pyramid(IMAGE)
    with pytest.raises(ValueError, match="uv: 1 of 4 values are NaN"):
        texture(tex, np.array([[0.1, np.nan], [0.2, 0.3]]))
    with pytest.raises(ValueError, match="image: 1 of"):
        mip_pyramid(np.where(np.arange(4).reshape(2, 2) == 3, np.nan, 0.5))
    with pytest.raises(ValueError, match=r"uv must have shape \(\.\.\., 2\)"):
        texture(tex, np.zeros((4, 3)))
    # under jit the values are checked by jaxgfx.checked
    bad = jnp.array([[0.1, jnp.inf]])
    assert np.isfinite(np.asarray(jax.jit(lambda u: texture(tex, u))(jnp.zeros((1, 2))))).all()
    with pytest.raises(ValueError, match="uv: 1 of 2 values are NaN or infinite"):
        jaxgfx.checked(jax.jit(lambda u: texture(tex, u)))(bad)
    v = np.zeros((3, 3), np.float32)
    f = np.array([[0, 1, 2]], np.int32)
    with pytest.raises(ValueError, match="uvs and texture go together"):
        mesh_pass(v, f, uvs=np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"uvs must have shape \(3, 2\)"):
        mesh_pass(v, f, uvs=np.zeros((2, 2)), texture=IMAGE)
    textured = mesh_pass(v, f, uvs=np.zeros((3, 2)), texture=IMAGE)
    with pytest.raises(ValueError, match="at most one of the meshes may have a texture"):
        merge_mesh_passes([textured, textured])
    merged = merge_mesh_passes([textured, mesh_pass(v, f)])
    np.testing.assert_array_equal(np.asarray(merged.textured)[:, 0], [1, 1, 1, 0, 0, 0])
