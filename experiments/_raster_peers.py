"""CPU peers of the rasterizer for ``experiments.bench_raster``: what a user would pick instead.

Each peer draws the same mesh from the same cameras and returns camera-space depth (camera z,
``+inf`` where nothing was hit), the quantity :func:`jaxgfx.rasterize` returns, so agreement
is per pixel:

- ``open3d`` — ``o3d.t.geometry.RaycastingScene`` (Intel Embree, every core).  It returns the
  distance along each unit ray, turned into camera z by the ray's cosine to the view axis.
  A batch of cameras is one ``cast_rays`` call on a (B, H, W, 6) ray tensor.
- ``llvmpipe`` — a real OpenGL rasterizer: Mesa's llvmpipe (every core) through a moderngl
  standalone EGL context.  The view's :func:`jaxgfx.camera.camera_matrix` is the MVP; the
  depth attachment is read back as float (inside the timing) and linearised to camera z.
- ``trimesh+embree`` — trimesh's ray caster with its embreex backend (one thread).

Set-up outside the timing: the scene/BVH or vertex buffers (once per mesh) and each camera's
rays or matrix (``prepare``: a few ms in NumPy).  Install: ``pip install '.[bench]'`` and the OS
packages ``libegl1 libgl1-mesa-dri libegl-mesa0`` (llvmpipe) and ``libusb-1.0-0`` (open3d).
A peer that cannot start is skipped with the reason (:func:`load_peers`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from jaxgfx.camera import Camera, camera_basis, camera_matrix, pixel_rays

__all__ = ["Open3dPeer", "LlvmpipePeer", "EmbreexPeer", "load_peers", "rays_of"]


def rays_of(cam: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit pixel rays of ``cam``: origins, directions (H, W, 3) and cos to the view axis."""
    o, d = (np.asarray(a, np.float32) for a in pixel_rays(cam, normalize=True))
    fwd = np.asarray(camera_basis(cam)[2], np.float32)
    return o, d, d @ fwd


class Open3dPeer:
    """open3d's Embree ray caster over every core."""

    name = "open3d"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        import open3d as o3d

        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)),
        )

    def prepare(self, cams: Sequence[Camera]):
        rays = [rays_of(c) for c in cams]
        packed = np.stack([np.concatenate([o, d], -1) for o, d, _ in rays])
        cos = np.stack([c for _, _, c in rays])
        return self._o3d.core.Tensor(np.ascontiguousarray(packed)), cos

    def run(self, state) -> np.ndarray:
        rays, cos = state
        t = self.scene.cast_rays(rays)["t_hit"].numpy()  # inf where missed
        return t * cos


class EmbreexPeer:
    """trimesh's ray caster on its embreex (Embree) backend; one thread."""

    name = "trimesh+embree"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        import trimesh
        from trimesh.ray.ray_pyembree import RayMeshIntersector  # needs embreex

        self.rmi = RayMeshIntersector(trimesh.Trimesh(vertices, faces, process=False))

    def prepare(self, cams: Sequence[Camera]):
        out = []
        for c in cams:
            o, d, _ = rays_of(c)
            fwd = np.asarray(camera_basis(c)[2], np.float64)
            out.append((o.reshape(-1, 3), d.reshape(-1, 3), fwd, o.shape[:2]))
        return out

    def run(self, state) -> np.ndarray:
        frames = []
        for o, d, fwd, shape in state:
            loc, ri, _ = self.rmi.intersects_location(o, d, multiple_hits=False)
            z = np.full(len(o), np.inf)
            z[ri] = (loc - o[ri]) @ fwd
            frames.append(z.reshape(shape))
        return np.stack(frames)


_VS = """
#version 330
uniform mat4 mvp;
in vec3 pos;
void main() { gl_Position = mvp * vec4(pos, 1.0); }
"""
_FS = """
#version 330
out vec4 col;
void main() { col = vec4(1.0); }
"""


class LlvmpipePeer:
    """Mesa llvmpipe (OpenGL 3.3+ software rasterizer) through a moderngl EGL context."""

    name = "llvmpipe"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        import moderngl

        self.ctx = moderngl.create_standalone_context(backend="egl")
        renderer = self.ctx.info.get("GL_RENDERER", "")
        if "llvmpipe" not in renderer:
            raise RuntimeError(f"EGL gives {renderer!r}, not Mesa llvmpipe")
        self.renderer = renderer
        self.prog = self.ctx.program(vertex_shader=_VS, fragment_shader=_FS)
        vbo = self.ctx.buffer(np.ascontiguousarray(vertices, np.float32).tobytes())
        ibo = self.ctx.buffer(np.ascontiguousarray(faces, np.int32).tobytes())
        self.vao = self.ctx.vertex_array(
            self.prog, [(vbo, "3f", "pos")], index_buffer=ibo, index_element_size=4
        )
        self.fbos: dict = {}

    def _fbo(self, w: int, h: int):
        if (w, h) not in self.fbos:
            depth = self.ctx.depth_texture((w, h))  # read back as float32 window depth
            color = self.ctx.renderbuffer((w, h))
            self.fbos[(w, h)] = self.ctx.framebuffer([color], depth)
        return self.fbos[(w, h)]

    def prepare(self, cams: Sequence[Camera]):
        return [
            (
                np.ascontiguousarray(np.asarray(camera_matrix(c), np.float32).T).tobytes(),
                (int(c.width), int(c.height)),
                (float(c.near), float(c.far)),
            )
            for c in cams
        ]

    def run(self, state) -> np.ndarray:
        import moderngl

        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)  # rasterize draws both sides by default
        frames = []
        for mvp, (w, h), (n, f) in state:
            fbo = self._fbo(w, h)
            fbo.use()
            fbo.clear(depth=1.0)
            self.prog["mvp"].write(mvp)  # column-major, hence the transpose in prepare
            self.vao.render(moderngl.TRIANGLES)
            d = np.frombuffer(
                fbo.read(components=1, attachment=-1, dtype="f4"), np.float32
            ).reshape(h, w)
            # window depth -> NDC z -> camera z (projection_matrix's inverse); row 0 at top
            z_ndc = 2.0 * d[::-1].astype(np.float64) - 1.0
            z = 2.0 * f * n / ((f + n) - z_ndc * (f - n))
            frames.append(np.where(d[::-1] < 1.0, z, np.inf))
        return np.stack(frames)


def load_peers(vertices: np.ndarray, faces: np.ndarray, names: Sequence[str] | None = None):
    """The peers that start on this machine, each built for the mesh.

    Returns:
        ``(peers, skipped)``: a list of peer objects (``name``, ``prepare(cams)``,
        ``run(state) -> (B, H, W) depth``) and ``{name: reason}`` for those that could not
        start (not installed, no EGL, ...); the reasons are printed.
    """
    peers, skipped = [], {}
    for cls in (Open3dPeer, LlvmpipePeer, EmbreexPeer):
        if names is not None and cls.name not in names:
            continue
        try:
            peers.append(cls(vertices, faces))
        except Exception as exc:  # ImportError, a missing libEGL, no llvmpipe, ...
            skipped[cls.name] = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
            print(f"peer {cls.name} skipped: {skipped[cls.name]}")
    return peers, skipped
