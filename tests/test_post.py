"""Screen-space post-processing (thesis 4.5.6)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgfx import post
from jaxgfx.camera import camera_from_degrees, pixel_rays

W, H = 40, 30


def _plane_depth(cam, normal, offset):
    """Exact depth of the plane n . p = offset seen by cam (inf where behind)."""
    o, d = pixel_rays(cam, normalize=False)
    t = (offset - o @ normal) / (d @ normal)
    return jnp.where(t > 0, t, jnp.inf)


def test_antialias_shapes_and_values():
    rng = np.random.default_rng(0)
    c = jnp.asarray(rng.random((6, 8, 3)), jnp.float32)
    d = jnp.asarray(rng.random((6, 8)) + 1, jnp.float32)
    c21, d21 = post.antialias(c, d, (2, 1))
    assert c21.shape == (6, 4, 3)
    np.testing.assert_allclose(c21, 0.5 * (c[:, 0::2] + c[:, 1::2]), atol=1e-6)
    np.testing.assert_allclose(d21, np.minimum(d[:, 0::2], d[:, 1::2]))
    c22, _ = post.antialias(c, d, (2, 2))
    np.testing.assert_allclose(c22[1, 2], c[2:4, 4:6].reshape(-1, 3).mean(0), atol=1e-6)
    with pytest.raises(ValueError, match="divisible"):
        post.antialias(c[:5], d[:5], (2, 2))


def test_smooth_keeps_constant_and_handles_empty():
    c = jnp.full((H, W, 3), 0.3)
    d = jnp.full((H, W), 5.0).at[:, :10].set(jnp.inf)
    out, dep = jax.jit(post.smooth)(c, d)
    assert np.all(np.isfinite(np.asarray(out)))
    np.testing.assert_allclose(np.asarray(out)[:, 12:], 0.3, atol=1e-6)
    # Far from the object, empty pixels stay empty and unchanged.
    assert np.all(np.isinf(np.asarray(dep)[:, :6]))
    # A hard vertical colour edge on one surface gets blended.
    c2 = jnp.where(jnp.arange(W)[None, :, None] < 25, 0.0, 1.0) * jnp.ones((H, W, 3))
    out2, _ = post.smooth(c2, jnp.full((H, W), 2.0))
    assert 0.0 < float(out2[15, 24, 0]) < 1.0


@pytest.mark.parametrize("normal", [(0.0, 0.0, -1.0), (0.5, 0.0, -1.0), (0.0, -0.6, -1.0)])
def test_screen_space_normals_of_a_plane(normal):
    cam = camera_from_degrees([0, 0, 0], 0, 0, 0, 60, W, H)
    n_cam = np.asarray(normal) / np.linalg.norm(normal)
    # Camera looks along +z with x-right = -x world at yaw 0: map the camera-space
    # normal to world space through the basis.
    from jaxgfx.camera import camera_basis

    r, u, f = (np.asarray(v) for v in camera_basis(cam))
    n_world = n_cam[0] * r + n_cam[1] * u + n_cam[2] * f
    depth = _plane_depth(cam, jnp.asarray(n_world, jnp.float32), 10.0 * float(n_world @ f))
    assert np.all(np.isfinite(np.asarray(depth)))
    got = np.asarray(post.screen_space_normals(cam, depth, key=jax.random.key(0)))
    inner = got[5:-5, 5:-5].reshape(-1, 3)
    np.testing.assert_allclose(inner, np.broadcast_to(n_cam, inner.shape), atol=0.03)


def test_ao_and_shade_finite():
    cam = camera_from_degrees([0, 0, 0], 0, 0, 0, 60, W, H)
    d = jnp.full((H, W), 10.0).at[10:20, 10:20].set(8.0).at[:, :3].set(jnp.inf)
    ao = post.ambient_occlusion(d, key=jax.random.key(1))
    assert np.all((np.asarray(ao) >= 0) & (np.asarray(ao) <= 1))
    # Next to a nearer block the far surface is occluded; the block itself is not.
    assert float(ao[15, 22]) < 1.0 and float(ao[15, 15]) == 1.0
    n = post.screen_space_normals(cam, d, key=jax.random.key(2))
    img = post.shade(jnp.full((H, W, 3), 0.8), n, ao)
    assert img.shape == (H, W, 3) and np.all(np.isfinite(np.asarray(img)))
    # The block stands 2 in front: it occludes within a gap of 3, not within 1.
    assert float(post.ambient_occlusion(d, key=jax.random.key(1), max_gap=3.0)[15, 22]) < 1.0
    assert float(post.ambient_occlusion(d, key=jax.random.key(1), max_gap=1.0)[15, 22]) == 1.0
    # vmap over frames agrees with single frames.
    batch = jax.vmap(lambda x: post.ambient_occlusion(x, key=jax.random.key(1)))(jnp.stack([d, d]))
    np.testing.assert_allclose(batch[1], ao)


def test_shade_voxels_lights_by_facing():
    # Left half a wall facing the camera, right half nearer to the right, so it
    # faces left, away from the light (which comes from the right): it is darker.
    cam = camera_from_degrees([0, 0, 0], 0, 0, 0, 60, W, H)
    xs = jnp.arange(W, dtype=jnp.float32)
    d = jnp.where(xs < W // 2, 10.0, 10.0 + 0.8 * (W - 1 - xs))[None, :].repeat(H, 0)
    d = d.at[:, -2:].set(jnp.inf)
    albedo = jnp.full((H, W, 3), 0.6)
    img = np.asarray(post.shade_voxels(cam, albedo, d, key=jax.random.key(0), background=(0, 0, 1)))
    assert img.shape == (H, W, 3) and np.all((img >= 0) & (img <= 1))
    np.testing.assert_array_equal(img[:, -2:], np.broadcast_to([0, 0, 1], (H, 2, 3)))
    facing, away = img[4:-4, 3 : W // 2 - 3, 0].mean(), img[4:-4, W // 2 + 3 : -5, 0].mean()
    assert facing > away + 0.05, (facing, away)
    with pytest.raises(ValueError, match="radius"):
        post.shade_voxels(cam, albedo, d, key=jax.random.key(0), ao_radius=0.0)
