"""Render passes joined into one frame with the shared camera (thesis 2.3-2.4).

A frame is the background pass followed by the main sub-passes (terrain,
static objects, characters), each producing a (colour, depth) frame with the
same :class:`~jaxgfx.camera.Camera`; :func:`~jaxgfx.compose.composite`
keeps the nearest sample per pixel.  This module holds the polygon pass used
for any triangle mesh and the default demo scene.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx import post, raycast, skin, terrain
from jaxgfx._src.checks import static_field
from jaxgfx.camera import Camera
from jaxgfx.compose import Frame, background, composite, fog, lambert
from jaxgfx.raster import rasterize, validate_mesh, vertex_normals

__all__ = [
    "MeshPass",
    "mesh_pass",
    "merge_mesh_passes",
    "render_mesh_pass",
    "render_frame",
    "demo_meshes",
    "grid_faces",
    "CharacterPass",
    "demo_character_pass",
    "character_pose",
    "render_character",
    "Demo",
    "build_demo",
    "demo_terrain",
    "terrain_mesh_pass",
    "VoxelPass",
    "demo_forest",
    "render_voxel_pass",
]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class MeshPass:
    """A lit triangle mesh for the polygon pass.

    Attributes:
        vertices: (V, 3) world positions.
        faces: (F, 3) int32 indices.
        colors: (V, 3) albedo in [0, 1].
        normals: (V, 3) unit normals.
    """

    vertices: jax.Array
    faces: jax.Array
    colors: jax.Array
    normals: jax.Array


def mesh_pass(vertices, faces, colors=None, normals=None) -> MeshPass:
    """Validates a mesh and builds a :class:`MeshPass` (normals computed if absent)."""
    validate_mesh(vertices, faces, colors)
    v = jnp.asarray(vertices, jnp.float32)
    f = jnp.asarray(faces, jnp.int32)
    c = jnp.full(v.shape, 0.7, jnp.float32) if colors is None else jnp.asarray(colors, jnp.float32)
    n = vertex_normals(v, f) if normals is None else jnp.asarray(normals, jnp.float32)
    return MeshPass(v, f, c, n)


def merge_mesh_passes(passes) -> MeshPass:
    """Concatenates several meshes into one pass (one rasterizer call)."""
    passes = list(passes)
    if not passes:
        raise ValueError("merge_mesh_passes: need at least one mesh")
    offs = np.cumsum([0] + [p.vertices.shape[0] for p in passes[:-1]])
    return MeshPass(
        jnp.concatenate([p.vertices for p in passes]),
        jnp.concatenate([p.faces + int(o) for p, o in zip(passes, offs)]),
        jnp.concatenate([p.colors for p in passes]),
        jnp.concatenate([p.normals for p in passes]),
    )


def render_mesh_pass(
    cam: Camera,
    mesh: MeshPass,
    light_dir=(0.4, 0.8, 0.3),
    ambient: float = 0.3,
    cull_backfaces: bool = False,
) -> Frame:
    """Rasterizes and Lambert-shades one mesh pass -> :class:`Frame`."""
    attrs = jnp.concatenate([mesh.colors, mesh.normals], axis=-1)
    out = rasterize(cam, mesh.vertices, mesh.faces, attrs, cull_backfaces=cull_backfaces)
    color = lambert(out.color[..., 3:], out.color[..., :3], light_dir, ambient)
    return Frame(color, out.depth)


def render_frame(
    cam: Camera,
    meshes,
    extra_frames=(),
    fog_density: float = 0.0,
    light_dir=(0.4, 0.8, 0.3),
) -> Frame:
    """Background + polygon passes + any other passes' frames, depth-composited.

    Args:
        cam: the camera shared by all passes.
        meshes: sequence of :class:`MeshPass` (merged into one rasterizer call).
        extra_frames: frames of other passes (voxels, terrain) for the same camera.
        fog_density: exponential fog density per world unit (0 = none).
        light_dir: direction towards the sun.
    """
    frames = [background(cam)]
    meshes = list(meshes)
    if meshes:
        frames.append(render_mesh_pass(cam, merge_mesh_passes(meshes), light_dir))
    frames.extend(extra_frames)
    return fog(composite(frames), density=fog_density)


def grid_faces(n: int) -> np.ndarray:
    """Faces (2 (n-1)^2, 3) int32 of an n x n vertex grid in row-major order, two per cell.

    Counter-clockwise seen from +y when rows run along +z and columns along +x.
    """
    i = np.arange(n - 1)
    ii, jj = np.meshgrid(i, i)
    a = (jj * n + ii).ravel()
    b, c = a + 1, a + n
    d = c + 1
    return np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]).astype(np.int32)


def demo_meshes(*, key: jax.Array, ground_cells: int = 96) -> list[MeshPass]:
    """The default demo scene: rolling ground, a sphere, a torus, a capsule, boxes.

    Needs no data files.  Hills are a sum of random Gaussian bumps drawn from ``key``.
    """
    import trimesh

    n = ground_cells + 1
    k1, k2, k3 = jax.random.split(key, 3)
    centers = np.asarray(jax.random.uniform(k1, (12, 2), minval=-30.0, maxval=30.0))
    heights = np.asarray(jax.random.uniform(k2, (12,), minval=-1.0, maxval=3.5))
    widths = np.asarray(jax.random.uniform(k3, (12,), minval=4.0, maxval=10.0))
    xs = np.linspace(-40.0, 40.0, n)
    gx, gz = np.meshgrid(xs, xs)
    gy = np.zeros_like(gx)
    for (cx, cz), h, w in zip(centers, heights, widths):
        gy += h * np.exp(-((gx - cx) ** 2 + (gz - cz) ** 2) / (2 * w * w))
    # Keep the middle flat where the objects stand.
    gy *= np.clip((np.hypot(gx, gz) - 6.0) / 6.0, 0.0, 1.0)
    gv = np.stack([gx, gy, gz], -1).reshape(-1, 3)
    gf = grid_faces(n)
    shade = np.clip(0.35 + 0.12 * gy, 0.2, 0.8)[..., None].reshape(-1, 1)
    gc = np.concatenate([0.45 * shade + 0.15, 0.55 + 0.0 * shade, 0.25 * shade + 0.1], -1)
    out = [mesh_pass(gv.astype(np.float32), gf.astype(np.int32), gc.astype(np.float32))]

    def add(m, color, offset):
        v = np.asarray(m.vertices, np.float32) + np.asarray(offset, np.float32)
        col = np.broadcast_to(np.asarray(color, np.float32), v.shape)
        out.append(mesh_pass(v, np.asarray(m.faces, np.int32), col))

    add(trimesh.creation.icosphere(subdivisions=4, radius=1.5), (0.85, 0.3, 0.25), (-3.0, 1.5, 2.0))
    add(trimesh.creation.torus(2.0, 0.6), (0.9, 0.75, 0.3), (3.0, 0.6, 3.0))
    add(trimesh.creation.capsule(height=3.0, radius=0.7), (0.3, 0.5, 0.9), (0.0, 2.2, 6.0))
    for k in range(5):
        s = 0.8 + 0.3 * k
        add(
            trimesh.creation.box((s, s, s)),
            (0.6, 0.6, 0.65),
            (-8.0 + 4.0 * k, s / 2, 11.0 + (k % 2) * 2.0),
        )
    return out


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CharacterPass:
    """A spline-skinned character with a deformation style, placed in the world (thesis ch. 5).

    Attributes:
        rig: the spline rig.
        binding: sampled-path binding (:func:`jaxgfx.skin.prepare_sampled`).
        style: the deformation style applied on each vertex's dominant spline.
        faces: (F, 3) int32 triangles of the bind mesh.
        color: (3,) albedo.
        scale: () uniform world scale.
        offset: (3,) world position of the rig origin.
        samples: static, spline samples of pass 1.
        styles: static, which envelopes: 'none', 'radial', 'rect' or 'both'.
    """

    rig: skin.SplineRig
    binding: skin.SampledBinding
    style: skin.Style
    faces: jax.Array
    color: jax.Array
    scale: jax.Array
    offset: jax.Array
    samples: int = static_field(32)
    styles: str = static_field("both")


def demo_character_pass(offset=(5.0, 0.0, 4.0), scale: float = 1.4) -> CharacterPass:
    """The demo character: :func:`jaxgfx.skin.demo_arm` with the muscle style."""
    arm = skin.demo_arm()
    return CharacterPass(
        rig=arm.rig,
        binding=skin.prepare_sampled(arm.binding, 32),
        style=skin.muscle_style(),
        faces=jnp.asarray(arm.faces),
        color=jnp.array([0.85, 0.62, 0.5], jnp.float32),
        scale=jnp.float32(scale),
        offset=jnp.asarray(offset, jnp.float32),
    )


def character_pose(ch: CharacterPass, phase: jax.Array) -> skin.SplinePose:
    """Animation of the demo arm: bend up to ~115 degrees and twist with ``phase`` in [0, 1)."""
    ang = 2.0 * jnp.pi * phase
    return skin.demo_arm_pose(ch.rig, 1.0 - jnp.cos(ang), 0.6 * jnp.sin(ang))


def render_character(
    cam: Camera, ch: CharacterPass, pose: skin.SplinePose, light_dir=(0.4, 0.8, 0.3)
) -> Frame:
    """Character pass: sampled spline skinning with the style, then the rasterizer."""
    pos, nrm = skin.skin_sampled(
        ch.rig, pose, ch.binding, ch.style, samples=ch.samples, styles=ch.styles
    )
    world = pos * ch.scale + ch.offset
    colors = jnp.broadcast_to(ch.color, world.shape)
    return render_mesh_pass(cam, MeshPass(world, ch.faces, colors, nrm), light_dir)


class Demo(NamedTuple):
    """The demo frame as timed passes sharing one camera (thesis 2.3, Fig. 2.2)."""

    camera: Camera
    passes: list  # [(name, fn, args, first-call seconds or None)]; Frames are composited
    composite: Callable  # jitted: list of Frames -> Frame
    description: str


def demo_terrain(*, key: jax.Array, size: int = 32, levels: int = 3):
    """Volumetric demo terrain: rolling hills (a heightmap) united with CSG rocks and arches.

    Returns:
        A :class:`jaxgfx.terrain.ClipBoxPipeline` of ``levels`` nested Clip-Boxes of
        ``size``^3 voxels (thesis ch. 3); the hills are flat around the origin.
    """
    k_hills, k_rocks = jax.random.split(key)
    n = 256
    xs = np.arange(n) - n / 2
    gx, gz = np.meshgrid(xs, xs)
    p = np.asarray(jax.random.uniform(k_hills, (40, 4)))
    h = np.zeros_like(gx)
    for cx, cz, a, w in p:
        cx, cz, a, w = (cx - 0.5) * n, (cz - 0.5) * n, -6 + 20 * a, 8 + 16 * w
        h += a * np.exp(-((gx - cx) ** 2 + (gz - cz) ** 2) / (2 * w * w))
    h *= np.clip((np.hypot(gx, gz) - 48) / 24, 0, 1)
    # The heightmap tiles with period n; centre the flat part on the origin.
    hills = terrain.heightmap_terrain(np.fft.ifftshift(h), base=int(np.floor(h.min())))
    rocks = terrain.random_csg_terrain(
        key=k_rocks,
        count=160,
        period=256,
        y_range=(-10, 36),
        radius=(3, 9),
        union_fraction=0.6,
        ground=-(10**6),
    )
    return terrain.ClipBoxPipeline(
        terrain.Union(hills, rocks), size=size, levels=levels, smoothing=4
    )


def terrain_mesh_pass(levels, voxel_size: float, color=(0.62, 0.56, 0.46)) -> MeshPass:
    """All Clip-Box levels (viewer-relative, anchored at the origin) as one :class:`MeshPass`."""
    v, n, f, _ = terrain.level_arrays(levels, (0, 0, 0))
    if f.shape[0] == 0:
        f = np.zeros((1, 3), np.int32)  # one degenerate triangle draws nothing
    verts = jnp.asarray(v, jnp.float32) * voxel_size
    return MeshPass(
        verts,
        jnp.asarray(f, jnp.int32),
        jnp.broadcast_to(jnp.asarray(color, jnp.float32), verts.shape),
        jnp.asarray(n, jnp.float32),
    )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class VoxelPass:
    """Static objects as run-length-encoded surface voxels placed in the world (thesis ch. 4).

    The ray caster works in voxel units; the pass moves and scales the shared
    camera into them (same orientation, field of view and resolution), so the
    depth it returns converts back to world units exactly.

    Attributes:
        rle: the (possibly instanced) scene, device arrays.
        origin: (3,) world position of voxel (0, 0, 0).
        voxel_size: () world units per voxel.
        num_planes: static ray-buffer planes (None: the renderer's default).
    """

    rle: raycast.RLEVolume
    origin: jax.Array
    voxel_size: jax.Array
    num_planes: int | None = static_field(None)


def demo_forest(*, key: jax.Array, origin=(-26.9, 0.0, 15.0), voxel_size: float = 0.14):
    """A row of procedural voxel trees (4.3.3) as instances of one RLE object (4.4.6)."""
    tree = raycast.procedural_tree(64, key=key, depth=4)
    rle = raycast.encode_rle(tree, levels=2)
    tiles = [(0, 0), (1, 1), (2, 0), (3, 1), (4, 0), (5, 1)]
    forest = raycast.place_instances(rle, tiles, (6, 2))
    return VoxelPass(
        raycast.as_jax(forest),
        jnp.asarray(origin, jnp.float32),
        jnp.float32(voxel_size),
    )


def render_voxel_pass(cam: Camera, vp: VoxelPass, *, key: jax.Array) -> Frame:
    """Per-plane RLE ray casting with the shared camera, lit by :func:`jaxgfx.post.shade_voxels`.

    Screen-space normals and ambient occlusion (4.5.6) from the voxel-space depth,
    with sample radii in voxels; black where nothing was hit.
    """
    local = dataclasses.replace(
        cam,
        position=(cam.position - vp.origin) / vp.voxel_size,
        near=cam.near / vp.voxel_size,
        far=cam.far / vp.voxel_size,
    )
    out = raycast.render_rle(
        vp.rle, local, settings=raycast.RenderSettings(num_planes=vp.num_planes)
    )
    color = post.shade_voxels(local, out.color, out.depth, key=key, samples=8)
    return Frame(color, out.depth * vp.voxel_size)


def build_demo(width: int, height: int, *, key: jax.Array) -> Demo:
    """Builds the default scene (no data files needed) and its jitted passes.

    Background sky; the terrain pass (3 nested Clip-Boxes of volumetric terrain,
    ch. 3); a polygon pass with primitives; a character pass (spline skinning
    with a muscle style, ch. 5).  Every pass uses the same camera and the
    frames are merged by depth.  Terrain generation is timed as a pass of its own.
    """
    import time

    from jaxgfx.camera import look_at

    k_terrain, k_objects, k_trees, k_ssn = jax.random.split(key, 4)
    cam = look_at([0.0, 6.0, -14.0], [1.0, 1.5, 6.0], 55.0, width, height, 0.1, 500.0)
    meshes = merge_mesh_passes(demo_meshes(key=k_objects)[1:])  # primitives, no ground
    ch = demo_character_pass(offset=(3.2, 0.0, -1.5), scale=1.6)
    pipe = demo_terrain(key=k_terrain)
    forest = demo_forest(key=k_trees)
    voxel = 0.5  # world units per level-0 voxel

    def generate_terrain(viewer):
        # Host-driven Clip-Box build (sampling, faces, smoothing, normals, welding).
        state = pipe.init(viewer)
        jax.block_until_ready(state)
        return terrain_mesh_pass(pipe.views(state), voxel)

    viewer = tuple(int(round(c / voxel)) for c in np.asarray(cam.position))
    t0 = time.perf_counter()
    terrain_pass = generate_terrain(viewer)
    first_build = time.perf_counter() - t0  # includes tracing and compiling every step
    render = jax.jit(render_mesh_pass)
    passes = [
        ("background pass", jax.jit(background), (cam,), None),
        ("terrain generation (3 Clip-Boxes of 32^3)", generate_terrain, (viewer,), first_build),
        ("terrain pass (rasterizer)", render, (cam, terrain_pass), None),
        ("polygon pass (rasterizer)", render, (cam, meshes), None),
        (
            "static objects pass (RLE voxel forest, per-plane ray caster)",
            jax.jit(lambda c, vp, k: render_voxel_pass(c, vp, key=k)),
            (cam, forest, k_ssn),
            None,
        ),
        (
            "character pass (spline skinning + style + rasterizer)",
            jax.jit(lambda c, ch, ph: render_character(c, ch, character_pose(ch, ph))),
            (cam, ch, jnp.float32(0.3)),
            None,
        ),
    ]
    desc = (
        f"terrain: {int(terrain_pass.faces.shape[0])} triangles; forest: 6 instances of one "
        f"procedural voxel tree; primitives: "
        f"{int(meshes.faces.shape[0])} triangles; character: "
        f"{int(ch.binding.rest.shape[0])} vertices on a spline rig with the muscle style"
    )
    comp = jax.jit(lambda fs: fog(composite(fs), density=0.012))
    return Demo(cam, passes, comp, desc)
