"""Cameras from anywhere: a COLMAP camera in every renderer, a pose fit that never locks.

Part 1, agreement.  One camera given as COLMAP gives it -- intrinsics ``K`` with
``fx != fy`` and a principal point off the image centre, and a world-to-camera ``[R|t]``
-- is built with :func:`jaxgfx.camera.camera_from_opencv` and drawn by the rasterizer
(a mesh), the RLE ray caster (the mesh voxelized) and the Clip-Box terrain (a height
map).  Each depth image is checked against rays made from ``K, R, t`` alone:

- open3d's ``RaycastingScene.create_rays_pinhole(K, [R|t], W, H)`` cast by Embree on the
  same mesh, the voxels' exposed cube faces and the terrain's drawn mesh, when open3d is
  installed (``pip install '.[bench]'``; skipped with the reason);
- else :func:`opencv_pixel_rays` (the pinhole formula in float64 NumPy) cast by trimesh;
  with open3d, the largest difference between its rays and these is given.

A pixel agrees when both miss, or both hit within 0.1 % of the scene's depth range (the
ray caster: within one voxel).  The round trips ``K, [R|t] -> Camera -> K, [R|t]`` and
OpenGL ``c2w -> Camera -> c2w`` are given as their largest error.

Part 2, a pose fit.  A camera looks straight down at a coloured ground plane (pitch -90
degrees, where yaw and roll turn the same way and Euler angles lock).  From starts 60
degrees away (random axes), Adam fits the camera's rotation to the target image (an L2
loss on the rasterized colours) two ways with the same steps and learning rate: through
the camera's quaternion, and through yaw/pitch/roll.  The table gives the final angle to
the target (median and worst) and the share of starts within 1 degree.

Usage::

    python -m experiments.camera_models --out out/camera_models
    python -m experiments.camera_models --quick --out out/camera_models
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys

import jax
import jax.numpy as jnp
import numpy as np
import optax

from experiments._rle_peers import cube_faces
from experiments.common import DATA, machine, markdown_table, write_table
from jaxgfx import raycast as RC
from jaxgfx import terrain as T
from jaxgfx.camera import (
    Camera,
    c2w_from_camera,
    camera_basis,
    camera_from_c2w,
    camera_from_opencv,
    opencv_from_camera,
    rotation_matrix,
    yaw_pitch_roll,
    yaw_pitch_roll_rotation,
)
from jaxgfx.raster import rasterize

__all__ = [
    "opencv_look_at",
    "opencv_intrinsics",
    "opencv_pixel_rays",
    "trimesh_depth",
    "depth_agreement",
    "environment_scene",
    "fit_rotation",
    "rotation_angle",
]


def opencv_look_at(eye, target, roll: float = 0.0):
    """World-to-camera ``(R (3, 3), t (3,))`` in OpenCV's axes (x right, y down, z forward).

    The camera at ``eye`` looks at ``target`` with the world's +y up on screen, turned by
    ``roll`` degrees about the view axis.  Written from the axes alone, in float64.
    """
    eye = np.asarray(eye, np.float64)
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(math.radians(roll)), math.sin(math.radians(roll))
    x, y = c * x + s * y, -s * x + c * y
    R = np.stack([x, y, z])
    return R, -R @ eye


def opencv_intrinsics(width: int, height: int, fov_y: float = 50.0) -> np.ndarray:
    """A COLMAP-like ``K``: ``fx = 1.07 fy`` and the principal point 9 % and 6 % off centre."""
    fy = 0.5 * height / math.tan(math.radians(fov_y) / 2)
    return np.array(
        [[1.07 * fy, 0.0, 0.59 * width], [0.0, fy, 0.44 * height], [0.0, 0.0, 1.0]], np.float64
    )


def opencv_pixel_rays(K, R, t, width: int, height: int):
    """Every pixel centre's ray from ``K, R, t`` alone, in float64 NumPy.

    Pixel ``(u, v)`` (column, row) sees along ``R^T K^-1 (u + 0.5, v + 0.5, 1)`` from the
    eye ``-R^T t``: the pinhole model of OpenCV and COLMAP.

    Returns:
        ``(origins, directions)``, each (H, W, 3); directions have camera-space z = 1, so
        a hit's ray parameter is its depth.
    """
    K, R, t = (np.asarray(a, np.float64) for a in (K, R, t))
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    pix = np.stack([u, v, np.ones_like(u)], -1)
    d_cam = pix @ np.linalg.inv(K).T
    d = d_cam @ R  # R^T d_cam per pixel
    o = np.broadcast_to(-R.T @ t, d.shape)
    return o, d


def open3d_pinhole_rays(K, R, t, width: int, height: int):
    """open3d's rays for the same camera, (H, W, 6) float32, or None (reason printed)."""
    try:
        import open3d as o3d
    except ImportError as e:
        print(f"open3d peer skipped: open3d not importable ({e}); pip install '.[bench]'")
        return None
    ext = np.eye(4)
    ext[:3, :3], ext[:3, 3] = R, t
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(K), o3d.core.Tensor(ext), width, height
    )
    return rays.numpy()


def open3d_depth(vertices, faces, rays, forward) -> np.ndarray:
    """Embree's depth (camera z) of open3d rays (H, W, 6) on a mesh; inf where missed."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(vertices, np.float32)),
        o3d.core.Tensor(np.asarray(faces, np.uint32)),
    )
    t_hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
    # create_rays_pinhole's directions are not unit: depth is t times their camera z.
    return t_hit * (rays[..., 3:] @ np.asarray(forward, np.float64))


def trimesh_depth(vertices, faces, origins, directions) -> np.ndarray:
    """trimesh's first hit of each ray (H, W, 3) on a mesh, as the ray parameter; inf if none."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), process=False)
    o, d = origins.reshape(-1, 3), directions.reshape(-1, 3)
    n = np.linalg.norm(d, axis=1)
    loc, idx, _ = mesh.ray.intersects_location(o, d / n[:, None], multiple_hits=True)
    out = np.full(len(o), np.inf)
    np.minimum.at(out, idx, np.linalg.norm(loc - o[idx], axis=1) / n[idx])
    return out.reshape(origins.shape[:-1])


def depth_agreement(ours, ref, tol: float) -> float:
    """Share of pixels where both miss, or both hit within ``tol``."""
    ours, ref = np.asarray(ours, np.float64), np.asarray(ref, np.float64)
    h1, h2 = np.isfinite(ours), np.isfinite(ref)
    both = h1 & h2
    close = np.abs(np.where(both, ours, 0.0) - np.where(both, ref, 0.0)) <= tol
    return float(np.mean((~h1 & ~h2) | (h1 & h2 & close)))


# ---------------------------------------------------------------------------
# Part 1: the three renderers
# ---------------------------------------------------------------------------


def mesh_scene(quick: bool):
    """``(name, vertices, faces)``: the bunny, or a procedural torus without the data.

    Quick: the pose fit's sphere (:func:`environment_scene`), so that the rasterizer
    compiles one program for both parts' frames of the same size (CI time).
    """
    if quick:
        v, f, _ = environment_scene()
        return "sphere", v, f
    import trimesh

    path = DATA / "meshes" / "bun_zipper.ply"
    if path.is_file():
        m = trimesh.load(path, process=False)
        return "bunny", np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32)
    m = trimesh.creation.torus(1.0, 0.35, major_sections=32, minor_sections=16)
    return "torus", np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32)


def camera_for(points, width: int, height: int, direction, roll: float):
    """``K, R, t`` of a COLMAP-like camera looking at ``points`` from ``direction``."""
    lo, hi = points.min(0), points.max(0)
    c, r = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    eye = c + 2.4 * r * np.asarray(direction, np.float64) / np.linalg.norm(direction)
    R, t = opencv_look_at(eye, c + 0.05 * r, roll)
    return opencv_intrinsics(width, height), R, t


def agreement_rows(quick: bool, width: int, height: int) -> list[dict]:
    rows = []
    name, v, f = mesh_scene(quick)
    res = 48 if quick else 128
    vox = RC.voxelize_mesh(v, f, res)
    rle = RC.as_jax(RC.encode_rle(vox))
    cv, cf, _ = cube_faces(vox)
    jobs = []
    K, R, t = camera_for(v, width, height, [0.5, 0.45, 1.0], 12.0)
    jobs.append((f"rasterize, {name}", K, R, t, v, f, lambda cam: rasterize(cam, v, f).depth, 1e-3))
    K2, R2, t2 = camera_for(cv, width, height, [-0.8, 0.6, 0.7], -9.0)
    jobs.append(
        (f"render_rle, {name} R={res}", K2, R2, t2, cv, cf,
         lambda cam: RC.render_rle(rle, cam).depth, None)
    )  # fmt: skip
    size = 32 if quick else 64
    # Quick: one clip box, no seams to mesh and weld (CI time).
    n_levels = 1 if quick else TERRAIN_LEVELS
    tv, tf, anchor, levels = terrain_mesh(terrain_map(quick), size, n_levels)
    K3, R3, t3 = terrain_camera(width, height, size, n_levels)
    jobs.append(
        (f"terrain, {'St Helens' if not quick else 'procedural'} map", K3, R3, t3, tv, tf,
         lambda cam: T.render_levels(cam, levels, anchor, rasterize_fn=jax.jit(rasterize)).depth,
         1e-3)
    )  # fmt: skip
    for label, K, R, t, mv, mf, draw, rel in jobs:
        cam = camera_from_opencv(K, R, t, width, height, near=1e-3, far=1e6)
        ours = np.asarray(draw(cam))
        row = dict(renderer=label, size=f"{width}x{height}")
        o, d = opencv_pixel_rays(K, R, t, width, height)
        fin = np.isfinite(ours)
        span = float(ours[fin].max() - ours[fin].min()) if fin.any() else 1.0
        tol = 1.0 if rel is None else rel * span
        row["hit_pct"] = round(100 * float(fin.mean()), 1)
        rays = open3d_pinhole_rays(K, R, t, width, height)
        if rays is not None:
            fwd = np.asarray(R[2], np.float64)
            row["o3d_agree_pct"] = round(
                100 * depth_agreement(ours, open3d_depth(mv, mf, rays, fwd), tol), 3
            )
            unit = d / np.linalg.norm(d, axis=-1, keepdims=True)
            o3d_unit = rays[..., 3:] / np.linalg.norm(rays[..., 3:], axis=-1, keepdims=True)
            row["o3d_ray_err"] = float(np.abs(unit - o3d_unit).max())
        if rays is None:
            row["trimesh_agree_pct"] = round(
                100 * depth_agreement(ours, trimesh_depth(mv, mf, o, d), tol), 3
            )
        rows.append(row)
    return rows


def terrain_map(quick: bool):
    """St Helens's DEM path (true scale), or a procedural hill (H, W) without the data."""
    path = DATA / "terrain" / "SainteHelens.dem"
    if not quick and path.is_file():
        return str(path)
    g = np.linspace(-1, 1, 64)
    x, z = np.meshgrid(g, g)
    return 24 * np.exp(-3 * (x * x + z * z)) + 4 * np.sin(5 * x)


TERRAIN_LEVELS = 3


def terrain_mesh(heights_or_path, size: int, n_levels: int = TERRAIN_LEVELS):
    """The terrain's drawn levels and their mesh: ``(vertices, faces, anchor, levels)``.

    Vertices are relative to the integer ``anchor`` (the viewer), as the terrain draws them.
    """
    terrain = T.heightmap_terrain(heights_or_path)
    pipe = T.ClipBoxPipeline(terrain, size=size, levels=n_levels)
    anchor = np.asarray(T.default_viewer(terrain), np.int64)
    levels = T.level_views(pipe.init(anchor))
    v, _, f, _ = T.level_arrays(levels, anchor)
    return v, f, anchor, levels


def terrain_camera(width: int, height: int, size: int, n_levels: int = TERRAIN_LEVELS):
    """``K, R, t`` above the drawn terrain's south side, looking down across it."""
    r = size * (1 << (n_levels - 1)) // 2  # the outer box's half-width
    eye = np.array([0.15 * r, 0.45 * r, -0.8 * r])
    return (
        opencv_intrinsics(width, height, 60.0),
        *opencv_look_at(eye, [0.0, -0.25 * r, 0.0], 5.0),
    )


def round_trips(seed: int = 0, cameras: int = 100) -> dict:
    """Largest errors of ``K,[R|t] -> Camera -> K,[R|t]`` and ``c2w -> Camera -> c2w``."""
    rng = np.random.default_rng(seed)
    err = dict(K_rel=0.0, R=0.0, t_rel=0.0, c2w=0.0)
    for _ in range(cameras):
        K = opencv_intrinsics(640, 480, rng.uniform(20, 100))
        K[:2, 2] += rng.uniform(-80, 80, 2)
        q = rng.normal(size=4)
        R = np.asarray(rotation_matrix(jnp.asarray(q / np.linalg.norm(q))), np.float64)
        R, _ = np.linalg.qr(R)
        R *= np.sign(np.linalg.det(R))
        t = rng.normal(size=3) * 10
        K2, R2, t2 = (np.asarray(a, np.float64) for a in opencv_from_camera(
            camera_from_opencv(K, R, t, 640, 480)))  # fmt: skip
        err["K_rel"] = max(err["K_rel"], float(np.abs(K2 - K).max() / np.abs(K).max()))
        err["R"] = max(err["R"], float(np.abs(R2 - R).max()))
        err["t_rel"] = max(err["t_rel"], float(np.abs(t2 - t).max() / np.linalg.norm(t)))
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = R.T, rng.normal(size=3)
        back = np.asarray(c2w_from_camera(camera_from_c2w(c2w, K, 640, 480)), np.float64)
        err["c2w"] = max(err["c2w"], float(np.abs(back - c2w).max() / max(1.0, np.abs(c2w).max())))
    return err


# ---------------------------------------------------------------------------
# Part 2: a pose fit at Euler angles' lock
# ---------------------------------------------------------------------------


def environment_scene(subdivisions: int = 2, radius: float = 10.0):
    """A sphere round the eye, coloured by direction: ``(vertices, faces, colours)``.

    Every orientation sees it whole, and a pixel's colour is (close to) a linear function
    of its ray's world direction, ``0.5 + 0.45 d``: the image loss of a rotation is then
    smooth on all of SO(3), with one minimum, so a fit fails only by its parametrization.
    """
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = np.asarray(m.vertices, np.float64)
    col = 0.5 + 0.45 * v / np.linalg.norm(v, axis=1, keepdims=True)
    return v.astype(np.float32), np.asarray(m.faces, np.int32), col.astype(np.float32)


def rotation_angle(q1, q2) -> float:
    """Angle in degrees between the rotations of two quaternions (any lengths)."""
    a = np.asarray(q1, np.float64) / np.linalg.norm(q1)
    b = np.asarray(q2, np.float64) / np.linalg.norm(q2)
    return math.degrees(2 * math.acos(min(1.0, abs(float(a @ b)))))


def turned(q, axis, degrees: float) -> np.ndarray:
    """Quaternion ``q`` turned by ``degrees`` about the world ``axis`` (float64)."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    h = math.radians(degrees) / 2
    r = np.concatenate([[math.cos(h)], math.sin(h) * axis])
    w1, v1 = r[0], r[1:]
    w2, v2 = q[0], np.asarray(q[1:], np.float64)
    return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + np.cross(v1, v2)])


def fit_rotation(loss_and_grad, q_start, *, euler: bool, steps: int, lr: float):
    """Adam on the quaternion or on yaw/pitch/roll; returns the final quaternion.

    ``loss_and_grad(q)`` is the image loss and its gradient with respect to the quaternion;
    through Euler angles the chain rule goes through :func:`yaw_pitch_roll_rotation`.  The
    learning rate decays to zero on a cosine over the steps.
    """
    opt = optax.adam(optax.cosine_decay_schedule(lr, steps))
    if euler:
        probe = Camera([0, 0, 0], q_start, [1, 1], [0, 0], 0.1, 1.0, 1, 1)
        params = jnp.stack([jnp.asarray(a, jnp.float32) for a in yaw_pitch_roll(probe)])
    else:
        params = jnp.asarray(q_start, jnp.float32)
    state = opt.init(params)
    for _ in range(steps):
        if euler:
            q = _euler_quaternion(params)
            _, g = _euler_pullback(params, loss_and_grad(q)[1])
        else:
            _, g = loss_and_grad(params)
        upd, state = opt.update(g, state)
        params = optax.apply_updates(params, upd)
    return np.asarray(_euler_quaternion(params) if euler else params, np.float64)


@jax.jit
def _euler_quaternion(p):
    return yaw_pitch_roll_rotation(p[0], p[1], p[2])


@jax.jit
def _euler_pullback(p, gq):
    """The gradient with respect to yaw/pitch/roll of one with respect to the quaternion."""
    q, pull = jax.vjp(lambda a: yaw_pitch_roll_rotation(a[0], a[1], a[2]), p)
    return q, pull(gq)[0]


def pose_problem(width: int, height: int):
    """``(loss_and_grad, target)``: the jitted image loss of a rotation and its target.

    The eye sits at the centre of :func:`environment_scene`; the target looks straight
    down (pitch -90 degrees, yaw 0.3 rad), where yaw and roll turn the view alike.
    """
    v, f, col = environment_scene()
    target = np.asarray(yaw_pitch_roll_rotation(0.3, -math.pi / 2, 0.0), np.float64)
    K = np.array([[0.8 * height, 0, width / 2], [0, 0.8 * height, height / 2], [0, 0, 1]])
    cam = camera_from_opencv(K, np.eye(3), np.zeros(3), width, height, near=0.05, far=100.0)

    def image(q):
        return rasterize(dataclasses.replace(cam, rotation=q), v, f, col).color

    ref = image(jnp.asarray(target, jnp.float32))
    loss = jax.jit(jax.value_and_grad(lambda q: jnp.mean((image(q) - ref) ** 2)))
    return loss, target


def start_axes(target, n: int, seed: int = 1) -> list[np.ndarray]:
    """Axes to turn the target by: its camera's up, right and view axes, then random ones."""
    probe = Camera([0, 0, 0], target, [1, 1], [0, 0], 0.1, 1.0, 1, 1)
    right, up, forward = (np.asarray(b, np.float64) for b in camera_basis(probe))
    rng = np.random.default_rng(seed)
    return ([up, right, forward, up + forward] + [rng.normal(size=3) for _ in range(n)])[:n]


def pose_rows(quick: bool) -> list[dict]:
    loss_and_grad, target = pose_problem(*((32, 24) if quick else (64, 48)))
    axes = start_axes(target, 1 if quick else 16)
    steps = 10 if quick else 300
    rows = []
    for label, euler in (("quaternion", False), ("yaw/pitch/roll", True)):
        final = np.array([
            rotation_angle(fit_rotation(loss_and_grad, turned(target, a, 60.0), euler=euler,
                                        steps=steps, lr=0.05), target)
            for a in axes
        ])  # fmt: skip
        rows.append(dict(parameters=label, starts=len(axes), steps=steps, start_deg=60.0,
                         median_deg=round(float(np.median(final)), 2),
                         worst_deg=round(float(np.max(final)), 2),
                         within_1deg_pct=round(100 * float(np.mean(final < 1.0)), 1)))  # fmt: skip
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="small scenes and frames, 2 fits of 10 steps"
    )
    ap.add_argument("--out", default="out/camera_models", help="folder for the tables")
    args = ap.parse_args(argv)
    width, height = (32, 24) if args.quick else (512, 384)
    agree = agreement_rows(args.quick, width, height)
    cameras = 10 if args.quick else 100  # quick: CI time
    trips = round_trips(cameras=cameras)
    fits = pose_rows(args.quick)
    text = (
        f"machine: {machine()}\n\n## Depth against rays from K, [R|t] alone\n\n"
        + markdown_table(
            agree,
            ["renderer", "size", "hit_pct", "o3d_agree_pct", "o3d_ray_err", "trimesh_agree_pct"],
        )  # fmt: skip
        + f"\n\n## Round trips (largest error over {cameras} random cameras)\n\n"
        + markdown_table([trips], list(trips))
        + "\n\n## Rotation fit to a straight-down view, from 60 degrees away\n\n"
        + markdown_table(fits, list(fits[0]))
    )
    title = "camera_models: COLMAP-style cameras in every renderer; pose fits"
    print(f"# {title}\n\n{text}")
    write_table(args.out, title, text, dict(machine=machine(), agreement=agree,
                                            round_trips=trips, pose_fit=fits))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
