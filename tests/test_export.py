"""Every public kernel lowers for CUDA and TPU (``jax.export`` on this CPU-only machine).

No accelerator is needed to lower: a program that exports for ``cuda`` and ``tpu`` compiles
there.  The batched programs must not map over frames on an accelerator: the ``vmap`` of a
kernel lowers for CUDA with the same number of ``while`` loops as one frame (every loop
advances the whole batch), while on CPU the frame-by-frame rule adds one loop over frames.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxgfx import raycast, silhouette, skin, terrain
from jaxgfx.camera import orbit_cameras
from jaxgfx.raster import rasterize

ACCELERATORS = ["cuda", "tpu"]


def _export(fn, *args, platforms=ACCELERATORS):
    exported = jax.export.export(jax.jit(fn), platforms=platforms)(*args)
    assert exported.nr_devices == 1
    return exported


def _whiles(exported) -> int:
    return exported.mlir_module().count("stablehlo.while")


@pytest.fixture(scope="module")
def mesh():
    m = trimesh.creation.icosphere(subdivisions=1)
    return np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32)


@pytest.fixture(scope="module")
def cams():
    return orbit_cameras([0, 0, 0], 3.0, n=4, width=16, height=12)


def _first(cams):
    return jax.tree_util.tree_map(lambda x: x[0], cams)


def test_rasterize_batches_on_accelerators_without_a_frame_loop(mesh, cams):
    v, f = mesh
    cam = _first(cams)
    one = _export(lambda c: rasterize(c, v, f).depth, cam)
    batch = _export(jax.vmap(lambda c: rasterize(c, v, f).depth), cams)
    cpu = _export(jax.vmap(lambda c: rasterize(c, v, f).depth), cams, platforms=["cpu"])
    cpu_one = _export(lambda c: rasterize(c, v, f).depth, cam, platforms=["cpu"])
    assert _whiles(batch) == _whiles(one) > 0
    assert _whiles(cpu) == _whiles(cpu_one) + 1  # lax.map over the frames on CPU
    posed = np.stack([v, v * 1.1])
    _export(jax.vmap(lambda vv: rasterize(cam, vv, f, vv).color), posed)


def test_rasterize_gradients_and_antialias_lower(mesh, cams):
    v, f = mesh
    cam = _first(cams)
    edges = silhouette.silhouette_edges(f)

    def loss(vv):
        out = rasterize(cam, vv, f, vv)
        img = silhouette.analytic_antialias(cam, vv, f, out, edges=edges)
        return jnp.sum(img) + jnp.sum(jnp.where(out.tri_id >= 0, out.depth, 0.0))

    _export(jax.grad(loss), v)
    _export(lambda c: jax.grad(lambda p: loss(v * p[0]))(jnp.ones(1)), cam)

    # A batch of antialiased images is one vectorized program: its outline walks are the
    # single image's loops (batched), with no loop over the frames.
    def image(c):
        return silhouette.analytic_antialias(c, v, f, rasterize(c, v, f, v), edges=edges)

    one, batch = _export(image, cam), _export(jax.vmap(image), cams)
    assert _whiles(batch) == _whiles(one) > 0


def test_render_rle_and_its_batch_lower():
    tree = raycast.procedural_tree(16, key=jax.random.key(0))
    rle = raycast.as_jax(raycast.encode_rle(tree, levels=2))
    cams = orbit_cameras([8.0, 8.0, 8.0], 40.0, n=2, width=16, height=12)
    one = _export(lambda c: raycast.render_rle(rle, c).depth, _first(cams))
    batch = _export(jax.vmap(lambda c: raycast.render_rle(rle, c).depth), cams)
    assert _whiles(batch) == _whiles(one)


def test_skinning_kernels_lower():
    rng = np.random.default_rng(0)
    t = np.tile(np.eye(3, 4, dtype=np.float32), (5, 1, 1))
    j = rng.integers(0, 5, (40, 4)).astype(np.int32)
    w = rng.random((40, 4)).astype(np.float32)
    w /= w.sum(1, keepdims=True)
    p = rng.normal(size=(40, 3)).astype(np.float32)
    for kernel in (skin.linear_blend_skinning, skin.dual_quaternion_skinning):
        _export(lambda t, kernel=kernel: kernel(t, p, p, j, w), t)
        _export(jax.vmap(lambda t, kernel=kernel: kernel(t, p, p, j, w)), np.stack([t, t]))
    arm = skin.demo_arm()
    pose = skin.demo_arm_pose(arm.rig, 0.5, 0.2)
    style = skin.muscle_style()
    _export(lambda pose: skin.skin_exact(arm.rig, pose, arm.binding, style), pose)
    sampled = skin.prepare_sampled(arm.binding, 8)
    _export(lambda pose: skin.skin_sampled(arm.rig, pose, sampled, style, samples=8), pose)


def test_terrain_sampling_and_meshing_lower():
    saw = terrain.SawTerrain()
    origin = jnp.zeros(3, jnp.int32)
    _export(lambda o: terrain.sample_terrain(saw, o, level=1, shape=(8, 8, 8)), origin)

    def mesh_of(o):
        box = terrain.sample_clipbox(saw, o, 0, size=8)
        return terrain.voxels_to_mesh(box, max_quads=256).vertices

    _export(mesh_of, origin)
