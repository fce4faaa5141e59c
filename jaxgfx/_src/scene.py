"""Render passes joined into one frame with the shared camera (thesis 2.3-2.4).

A frame is the background pass followed by the main sub-passes (terrain,
static objects, characters), each producing a (colour, depth) frame with the
same :class:`~jaxgfx.camera.Camera`; :func:`~jaxgfx.compose.composite`
keeps the nearest sample per pixel.  This module holds the polygon pass used
for any triangle mesh and the default demo scene.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera
from jaxgfx._src.checks import static_field
from jaxgfx._src.compose import Frame, background, composite, fog, lambert
from jaxgfx._src.post import shade_voxels
from jaxgfx._src.raster import rasterize, validate_mesh, vertex_normals
from jaxgfx._src.texture import MipTexture, mip_pyramid, texture, uv_footprint
from jaxgfx._src.voxel.encode import RLEVolume
from jaxgfx._src.voxel.render import render_rle
from jaxgfx._src.voxel.settings import RenderSettings

__all__ = [
    "MeshPass",
    "mesh_pass",
    "merge_mesh_passes",
    "render_mesh_pass",
    "render_frame",
    "grid_faces",
    "VoxelPass",
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
        uvs: (V, 2) texture coordinates, (0, 0) the texture's top-left corner; None
            without a texture.
        textured: (V, 1) 1 where the vertex's albedo is multiplied by the texture, else 0;
            None without a texture.
        texture: the :func:`~jaxgfx.raster.mip_pyramid` of the pass's texture, or None.
    """

    vertices: jax.Array
    faces: jax.Array
    colors: jax.Array
    normals: jax.Array
    uvs: jax.Array | None = None
    textured: jax.Array | None = None
    texture: MipTexture | None = None


def mesh_pass(vertices, faces, colors=None, normals=None, uvs=None, texture=None) -> MeshPass:
    """Validates a mesh and builds a :class:`MeshPass` (normals computed if absent).

    Args:
        vertices: (V, 3) positions.
        faces: (F, 3) vertex indices.
        colors: (V, 3) albedo in [0, 1] (0.7 grey if None); a texture multiplies it.
        normals: (V, 3) normals, computed from the faces if None.
        uvs: (V, 2) texture coordinates, required with ``texture``.
        texture: (H, W, C) image (uint8 or floats in [0, 1]) or a
            :class:`~jaxgfx.raster.MipTexture`.

    Raises:
        ValueError: bad shapes, or ``texture`` without ``uvs`` (or the reverse).
    """
    validate_mesh(vertices, faces, colors)
    v = jnp.asarray(vertices, jnp.float32)
    f = jnp.asarray(faces, jnp.int32)
    c = jnp.full(v.shape, 0.7, jnp.float32) if colors is None else jnp.asarray(colors, jnp.float32)
    n = vertex_normals(v, f) if normals is None else jnp.asarray(normals, jnp.float32)
    if (uvs is None) != (texture is None):
        raise ValueError("uvs and texture go together: pass both or neither")
    if uvs is None:
        return MeshPass(v, f, c, n)
    uv = jnp.asarray(uvs, jnp.float32)
    if uv.shape != (v.shape[0], 2):
        raise ValueError(f"uvs must have shape ({v.shape[0]}, 2), got {uv.shape}")
    tex = texture if isinstance(texture, MipTexture) else mip_pyramid(texture)
    return MeshPass(v, f, c, n, uv, jnp.ones((v.shape[0], 1)), tex)


def merge_mesh_passes(passes) -> MeshPass:
    """Concatenates several meshes into one pass (one rasterizer call)."""
    passes = list(passes)
    if not passes:
        raise ValueError("merge_mesh_passes: need at least one mesh")
    offs = np.cumsum([0] + [p.vertices.shape[0] for p in passes[:-1]])
    textures = [p.texture for p in passes if p.texture is not None]
    if len(textures) > 1:
        raise ValueError("merge_mesh_passes: at most one of the meshes may have a texture")
    uvs = textured = None
    if textures:  # the untextured meshes keep their albedo (textured = 0)
        n = [p.vertices.shape[0] for p in passes]
        uvs = jnp.concatenate(
            [p.uvs if p.texture is not None else jnp.zeros((k, 2)) for p, k in zip(passes, n)]
        )
        textured = jnp.concatenate(
            [p.textured if p.texture is not None else jnp.zeros((k, 1)) for p, k in zip(passes, n)]
        )
    return MeshPass(
        jnp.concatenate([p.vertices for p in passes]),
        jnp.concatenate([p.faces + int(o) for p, o in zip(passes, offs)]),
        jnp.concatenate([p.colors for p in passes]),
        jnp.concatenate([p.normals for p in passes]),
        uvs,
        textured,
        textures[0] if textures else None,
    )


def render_mesh_pass(
    cam: Camera,
    mesh: MeshPass,
    light_dir=(0.4, 0.8, 0.3),
    ambient: float = 0.3,
    cull_backfaces: bool = False,
) -> Frame:
    """Rasterizes and Lambert-shades one mesh pass -> :class:`~jaxgfx.compose.Frame`.

    A textured pass multiplies each pixel's albedo by the texture at its UV, filtered by
    the UVs' footprint (:func:`~jaxgfx.raster.texture`).
    """
    tex = mesh.texture
    attrs = [mesh.colors, mesh.normals]
    if tex is not None and mesh.uvs is not None and mesh.textured is not None:
        attrs += [mesh.uvs, mesh.textured]
    else:
        tex = None
    out = rasterize(cam, mesh.vertices, mesh.faces, jnp.concatenate(attrs, axis=-1),
                    cull_backfaces=cull_backfaces)  # fmt: skip
    albedo = out.color[..., :3]
    if tex is not None:
        uv, t = out.color[..., 6:8], out.color[..., 8:9]
        rgb = texture(tex, uv, uv_footprint(uv, out.tri_id))[..., :3]
        albedo = albedo * (1.0 - t + t * rgb)
    color = lambert(out.color[..., 3:6], albedo, light_dir, ambient)
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
    sky = background(cam)
    frames = [sky]
    meshes = list(meshes)
    if meshes:
        frames.append(render_mesh_pass(cam, merge_mesh_passes(meshes), light_dir))
    frames.extend(extra_frames)
    # far geometry fades into the sky behind each pixel, not into one flat colour
    return fog(composite(frames), sky.color, density=fog_density)


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

    rle: RLEVolume
    origin: jax.Array
    voxel_size: jax.Array
    num_planes: int | None = static_field(None)


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
    out = render_rle(vp.rle, local, settings=RenderSettings(num_planes=vp.num_planes))
    color = shade_voxels(local, out.color, out.depth, key=key, samples=8)
    return Frame(color, out.depth * vp.voxel_size)
