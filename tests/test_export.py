"""Every public kernel lowers for CUDA and TPU (``jax.export`` on this CPU-only machine).

No accelerator is needed to lower: a program that exports for ``cuda`` and ``tpu`` compiles
there.  The batched programs must not loop over frames on an accelerator: the ``vmap`` of a
kernel lowers for CUDA and TPU with exactly the ``while`` loops of one frame (every loop
advances the whole batch), and that count is pinned, so a loop added to a kernel fails here
until its comment below says what it is.  On the CPU the frame-by-frame batching rule
(``jaxgfx._src.frames.per_frame``) adds exactly one loop, over the frames.

Frames are 640x480, large enough for XLA:CPU's shading in stripes of rows (2 stripes there).
``jax.export`` traces and lowers but does not compile; each function is traced once and
lowered once per platform set.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxgfx import raycast, silhouette, skin, terrain
from jaxgfx._src.skin.baselines import POSE_CHUNK
from jaxgfx.camera import orbit_cameras
from jaxgfx.raster import rasterize

ACCELERATORS = ["cuda", "tpu"]
W, H = 640, 480
FRAME_LOOP = 1  # the CPU's lax.map over the frames of a batch


def _export(jitted, *args, platforms=ACCELERATORS):
    exported = jax.export.export(jitted, platforms=platforms)(*args)
    assert exported.nr_devices == 1
    return exported


def _whiles(exported) -> int:
    # Textual count: a private function called twice (one binary search's program for two
    # queries of one shape) counts once.
    return exported.mlir_module().count("stablehlo.while")


def _loops(fn, *args, cpu: bool) -> tuple[int, int | None]:
    """``stablehlo.while`` ops of ``fn``'s lowering for CUDA and TPU, and for the CPU if ``cpu``."""
    jitted = jax.jit(fn)  # one trace, lowered once per platform set
    acc = _whiles(_export(jitted, *args))
    return acc, _whiles(_export(jitted, *args, platforms=["cpu"])) if cpu else None


def _pin(fn, frame, batch, *, loops: int, cpu_frame_loop: int | None = None) -> int | None:
    """Asserts the loop rule for ``fn`` of one frame and its ``vmap`` over ``batch``.

    ``cpu_frame_loop``: the loops the CPU's batch adds to its frame's (the frames rule's one),
    checked from the CPU's lowerings; ``None`` for kernels vmapped as they are everywhere.
    Returns the CPU's loop count for one frame (``None`` without the CPU's lowerings).
    """
    cpu = cpu_frame_loop is not None
    acc_one, cpu_one = _loops(fn, *frame, cpu=cpu)
    acc_batch, cpu_batch = _loops(jax.vmap(fn), *batch, cpu=cpu)
    assert acc_one == loops, f"one frame lowers with {acc_one} loops, pinned {loops}"
    assert acc_batch == acc_one, "the accelerator batch loops over its frames"
    if cpu:
        assert cpu_batch == cpu_one + cpu_frame_loop
    return cpu_one


@pytest.fixture(scope="module")
def mesh():
    m = trimesh.creation.icosphere(subdivisions=1)
    return np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32)


@pytest.fixture(scope="module")
def cams():
    return orbit_cameras([0, 0, 0], 3.0, n=2, width=W, height=H)


def _first(tree):
    return jax.tree_util.tree_map(lambda x: x[0], tree)


# rasterize's loops in one frame of a mesh under 65,536 faces (one face batch: larger meshes
# add the loop over face batches, a static trip count): the clipped triangles' halves (1 or 2
# trips: the second only where a face crosses the near plane), the z-buffer's work-list
# chunks (ceil(tiles / chunk) + 1 trips) and, inside it, the binary search that finds each
# tile's triangle (ceil(log2(T + 1)) trips for T triangles).  The CPU adds the shading's
# stripes of rows (lax.map).
RASTER_LOOPS = 3
STRIPES = 1


def test_rasterize_batches_on_accelerators_without_a_frame_loop(mesh, cams):
    import jaxgfx._src.raster as raster

    assert raster._stripes(H, W) == 2  # the frame size exercises the CPU's stripes
    v, f = mesh

    def colour(cam):
        return rasterize(cam, v, f, v).color

    cpu = _pin(colour, (_first(cams),), (cams,), loops=RASTER_LOOPS, cpu_frame_loop=FRAME_LOOP)
    assert cpu == RASTER_LOOPS + STRIPES
    # One program for every platform: each platform_dependent lowers both its branches, under
    # vmap too.
    both = _export(jax.jit(jax.vmap(colour)), cams, platforms=["cpu", *ACCELERATORS])
    assert both.platforms == ("cpu", *ACCELERATORS)


def test_rasterize_gradients_lower_without_loops_of_their_own(mesh, cams):
    v, f = mesh
    cam = _first(cams)

    def loss(vv):
        out = rasterize(cam, vv, f, vv)
        return jnp.sum(out.color) + jnp.sum(jnp.where(out.tri_id >= 0, out.depth, 0.0))

    # The gradient renders the frame once and differentiates its shading in closed form,
    # which has no loop on any platform; on the CPU the frame's own shading runs in stripes.
    posed = np.stack([v, v * 1.1])
    cpu = _pin(jax.grad(loss), (v,), (posed,), loops=RASTER_LOOPS, cpu_frame_loop=FRAME_LOOP)
    assert cpu == RASTER_LOOPS + STRIPES
    _export(jax.jit(lambda c: jax.grad(lambda p: loss(v * p[0]))(jnp.ones(1))), cam)


def test_antialias_batch_is_one_vectorized_program(mesh, cams):
    v, f = mesh
    edges = silhouette.silhouette_edges(f)

    def image(cam):
        return silhouette.analytic_antialias(cam, v, f, rasterize(cam, v, f, v), edges=edges)

    # Beyond rasterize's: the pool of outline walks (one step per face crossed by its lanes,
    # until the queue of candidate pairs is empty) and the blends of outline pairs beyond the
    # first block (none unless outlines fill more than 1/32 of the pair slots).
    # The batch is vectorized on accelerators; the CPU runs the frames of rasterize and of
    # the walks one after the other (a frames loop each).
    cpu = _pin(
        image, (_first(cams),), (cams,), loops=RASTER_LOOPS + 2, cpu_frame_loop=2 * FRAME_LOOP
    )
    assert cpu == RASTER_LOOPS + STRIPES + 2


def test_render_rle_batch_has_one_frames_loops():
    tree = raycast.procedural_tree(16, key=jax.random.key(0))
    rle = raycast.as_jax(raycast.encode_rle(tree, levels=2))
    cams = orbit_cameras([8.0, 8.0, 8.0], 40.0, n=2, width=W, height=H)

    def depth(cam):
        return raycast.render_rle(rle, cam).depth

    # The scatter traversal (the default for this map): its passes over the texel table
    # (ceil(texels / span) trips) and, in each, its window steps (data-dependent, one per
    # window of (element, plane) pairs; docs/design/raycast.md counts them per frame); the
    # bucketed search that ranks each cell's planes (a static trip count); and four of
    # jnp.searchsorted's binary searches (ceil(log2) trips: each plane's segment, a pass's
    # planes, a window's first pair and the pairs' elements).
    cpu = _pin(depth, (_first(cams),), (cams,), loops=7, cpu_frame_loop=FRAME_LOOP)
    assert cpu == 7


def test_cast_rays_is_one_loop_as_wide_as_its_rays():
    # cast_rays: one loop over the map cells each ray crosses (data-dependent, at most
    # X + Z + 1 steps), advancing every ray of the batch together; vmap over batches of rays
    # keeps that one loop.
    tree = raycast.procedural_tree(16, key=jax.random.key(0))
    rle = raycast.as_jax(raycast.encode_rle(tree))
    origins = jnp.zeros((2, W, 3)) - 5.0
    directions = jnp.ones((2, W, 3))
    # On the CPU the loop is the wavefront's (live walks refilled from the queue), one too.
    cpu = _pin(lambda o, d: raycast.cast_rays(rle, o, d).t, (origins[0], directions[0]),
               (origins, directions), loops=1, cpu_frame_loop=0)  # fmt: skip
    assert cpu == 1


def test_skinning_kernels_batch_without_loops():
    rng = np.random.default_rng(0)
    t = np.tile(np.eye(3, 4, dtype=np.float32), (5, 1, 1))
    j = rng.integers(0, 5, (40, 4)).astype(np.int32)
    w = rng.random((40, 4)).astype(np.float32)
    w /= w.sum(1, keepdims=True)
    p = rng.normal(size=(40, 3)).astype(np.float32)
    # Two chunks of poses: on the CPU the frames rule maps chunks of POSE_CHUNK poses (a
    # batch of at most one chunk is vectorized whole, with no loop).
    poses = np.stack([t] * 2 * POSE_CHUNK)
    for kernel in (skin.linear_blend_skinning, skin.dual_quaternion_skinning):
        cpu = _pin(
            lambda t, kernel=kernel: kernel(t, p, p, j, w),
            (t,),
            (poses,),
            loops=0,
            cpu_frame_loop=FRAME_LOOP,
        )
        assert cpu == 0
    arm = skin.demo_arm()
    pose = skin.demo_arm_pose(arm.rig, 0.5, 0.2)
    arm_poses = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), pose)
    style = skin.muscle_style()
    sampled = skin.prepare_sampled(arm.binding, 8)
    # Spline skinning is per vertex, vmapped as it is on every platform.
    for fn in (
        lambda q: skin.skin_exact(arm.rig, q, arm.binding, style),
        lambda q: skin.skin_sampled(arm.rig, q, sampled, style, samples=8),
    ):
        _pin(fn, (pose,), (arm_poses,), loops=0)


def test_terrain_sampling_and_meshing_batch_without_loops():
    saw = terrain.SawTerrain()
    origin = jnp.zeros(3, jnp.int32)
    origins = jnp.zeros((2, 3), jnp.int32)

    def mesh_of(o):
        box = terrain.sample_clipbox(saw, o, 0, size=8)
        return terrain.voxels_to_mesh(box, max_quads=256).vertices

    # Vmapped as they are on every platform.
    for fn in (
        lambda o: terrain.sample_terrain(saw, o, level=1, shape=(8, 8, 8)),
        lambda o: terrain.sample_clipbox(saw, o, 0, size=8),
        mesh_of,
    ):
        _pin(fn, (origin,), (origins,), loops=0)


def test_texture_lookups_lower_without_loops():
    # texture: gathers from the packed pyramid, one per corner and level; uv_footprint: shifts
    # of the frame.  No loop on any platform, one frame or a batch.
    from jaxgfx.raster import mip_pyramid, texture, uv_footprint

    tex = mip_pyramid(np.zeros((64, 64, 3), np.float32))
    uv = jnp.zeros((2, H, W, 2))
    tid = jnp.zeros((2, H, W), jnp.int32)
    _pin(
        lambda u, t: texture(tex, u, uv_footprint(u, t)), (uv[0], tid[0]), (uv, tid),
        loops=0, cpu_frame_loop=0,
    )  # fmt: skip
