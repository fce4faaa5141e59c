"""Compositing, background, shading, depth image, atomic PNG output."""

from __future__ import annotations

import dataclasses

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgfx.camera import camera_from_degrees, yaw_pitch_roll_rotation
from jaxgfx.compose import Frame, background, composite, depth_image, fog, lambert, to_uint8
from jaxgfx.io import atomic_write, save_png


def test_composite_keeps_nearest_per_pixel():
    rng = np.random.default_rng(0)
    frames = []
    for k in range(3):
        d = rng.uniform(1, 10, (5, 7)).astype(np.float32)
        d[rng.uniform(size=d.shape) < 0.3] = np.inf
        frames.append(Frame(jnp.full((5, 7, 3), k / 2.0), jnp.asarray(d)))
    out = composite(frames)
    depths = np.stack([np.asarray(f.depth) for f in frames])
    np.testing.assert_array_equal(np.asarray(out.depth), depths.min(0))
    idx = np.argmin(depths, 0)  # first minimum wins ties, like composite
    np.testing.assert_allclose(np.asarray(out.color)[..., 0], idx / 2.0)
    with pytest.raises(ValueError, match="non-empty"):
        composite([])
    with pytest.raises(ValueError, match="shapes"):
        composite([frames[0], Frame(jnp.zeros((2, 2, 3)), jnp.zeros((2, 2)))])


def test_background_sky_above_ground_below():
    cam = camera_from_degrees([0, 0, 0], 0, 0, 0, 90, 8, 8)
    bg = background(cam, horizon=(1, 1, 1), zenith=(0, 0, 1), ground=(0, 1, 0))
    c = np.asarray(bg.color)
    assert np.all(np.isinf(np.asarray(bg.depth)))
    assert c[0, 4, 0] < 1.0 and c[0, 4, 2] == pytest.approx(1.0)  # top row: towards zenith
    assert c[-1, 4, 1] == pytest.approx(1.0) and c[-1, 4, 0] < 1.0  # bottom row: ground
    # looking straight down is all ground, finite
    down = background(camera_from_degrees([0, 0, 0], 0, -90, 0, 60, 8, 8))
    assert np.all(np.isfinite(np.asarray(down.color)))


def test_background_gradients_wrt_the_camera_are_finite_and_right():
    # Rows above and below the horizon: sqrt's infinite slope at 0 must not turn the ground
    # rows' zero cotangents into NaN.  d/dpitch matches a central difference.
    cam = camera_from_degrees([0, 0, 0], 10, 5, 0, 60, 16, 12)

    @jax.jit
    def total(pitch, yaw):
        rotation = yaw_pitch_roll_rotation(yaw, pitch, 0.0)
        return jnp.sum(background(dataclasses.replace(cam, rotation=rotation)).color)

    g_pitch, g_yaw = jax.grad(total, (0, 1))(cam.pitch, cam.yaw)
    assert np.isfinite(float(g_pitch)) and np.isfinite(float(g_yaw))
    h = 1e-3
    fd = (total(cam.pitch + h, cam.yaw) - total(cam.pitch - h, cam.yaw)) / (2 * h)
    assert float(g_pitch) == pytest.approx(float(fd), rel=2e-2)
    assert abs(float(g_pitch)) > 1.0  # the horizon moves through the rows


def test_lambert_and_fog():
    n = jnp.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.0]])
    alb = jnp.ones((3, 3))
    out = np.asarray(lambert(n, alb, light_dir=(0, 1, 0), ambient=0.2, two_sided=False))
    np.testing.assert_allclose(out[:, 0], [1.0, 0.2, 0.2], atol=1e-6)
    fr = Frame(jnp.zeros((1, 3, 3)), jnp.array([[0.0, 100.0, jnp.inf]]))
    f = np.asarray(fog(fr, fog_color=(1, 1, 1), density=0.1).color)[0, :, 0]
    assert f[0] == 0.0 and f[1] == pytest.approx(1 - np.exp(-10.0), rel=1e-5) and f[2] == 0.0


def test_depth_image_bright_near_dark_far():
    d = jnp.array([[1.0, 2.0, 10.0, jnp.inf]])
    g = np.asarray(depth_image(d))[0]
    assert g[0] > g[1] > g[2] > g[3] == 0.0
    assert np.all((g >= 0) & (g <= 1))
    assert np.all(np.asarray(depth_image(jnp.full((2, 2), jnp.inf))) == 0)


def test_save_png_atomic_roundtrip(tmp_path):
    img = np.linspace(0, 1, 4 * 5 * 3).reshape(4, 5, 3)
    p = save_png(tmp_path / "a" / "img.png", img)
    back = iio.imread(p)
    np.testing.assert_array_equal(back, np.asarray(to_uint8(img)))
    with pytest.raises(ValueError, match="non-finite"):
        save_png(tmp_path / "b.png", np.full((2, 2), np.nan))
    with pytest.raises(ValueError, match="image must be"):
        save_png(tmp_path / "c.png", np.zeros((2, 2, 5)))
    # a failure while writing leaves neither a partial file nor a temp file
    with pytest.raises(RuntimeError):
        with atomic_write(tmp_path / "d.bin") as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("interrupted")
    assert not (tmp_path / "d.bin").exists()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a"]


def test_atomic_files_get_normal_permissions(tmp_path):
    import os

    p = save_png(tmp_path / "p.png", np.zeros((2, 2)))
    umask = os.umask(0)
    os.umask(umask)
    assert (p.stat().st_mode & 0o777) == (0o666 & ~umask)


def test_fog_fades_into_the_sky_behind_each_pixel():
    cam = camera_from_degrees([0, 0, 0], 0, 10, 0, 60, 6, 8)
    sky = background(cam)
    # every pixel hit by a grey object far away: it takes the sky's colour at that pixel
    far = Frame(jnp.full((8, 6, 3), 0.5), jnp.full((8, 6), 1e4))
    out = np.asarray(fog(far, sky.color, density=1.0).color)
    np.testing.assert_allclose(out, np.asarray(sky.color), atol=1e-6)
    assert np.ptp(out[:, 0, 2]) > 0.05  # the sky's gradient, not one flat fog colour
    near = Frame(jnp.full((8, 6, 3), 0.5), jnp.full((8, 6), 1e-6))
    np.testing.assert_allclose(np.asarray(fog(near, sky.color, density=1.0).color), 0.5, atol=1e-5)
    with pytest.raises(ValueError, match="fog_color"):
        fog(far, jnp.zeros((2, 2, 3)), density=1.0)
    with pytest.raises(ValueError, match="density"):
        fog(far, density=-1.0)
