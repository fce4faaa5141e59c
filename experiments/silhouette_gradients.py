"""Silhouette gradients: analytic antialiasing against finite differences and supersampling.

:func:`jaxgfx.silhouette.analytic_antialias` turns a z-buffer coverage image into one that is
continuous in the geometry, so that its sums (area, centroid, an image loss) have derivatives.
This experiment holds those derivatives, taken by autodiff, against two references:

* central finite differences of the antialiased image itself over steps of about one pixel of
  edge motion (steps that cross pixel centres, where the raw coverage flips);
* a supersampled coverage (``--samples`` x ``--samples`` samples per pixel, rasterized by
  :func:`jaxgfx.raster.rasterize` on :func:`jaxgfx.camera.supersampled` and averaged down), an
  independent estimate of the covered area and centroid, differentiated by the same finite
  differences.

(a) The sphere: an icosphere (3 subdivisions, 642 vertices) of radius 0.8, 3 units from a 96x72
    camera (60 degree vertical field of view), scaled by ``s`` about its centre.  The covered
    area ``A(s)`` and ``dA/ds`` by autodiff, by central differences over +-2 %, by the
    supersampled area's differences, and in closed form: the exact projected area of the mesh
    (the convex hull of its projected vertices, float64), and for the round sphere
    ``A = pi f^2 r^2 / (d^2 - r^2)``, ``dA/ds = 2 A d^2 / (d^2 - r^2)`` (``2 A`` is its
    orthographic limit).  Continuity: ``A(s)`` over 41 scales in [0.99, 1.01]; every step should
    be the mean step (the largest departure is reported).
(b) Sums of the image (area, centroid x and y, and an L2 loss against the image of a displaced
    copy) under translation, rotation and scale of the mesh and under camera motion, for the
    sphere, the demo limb (posed) and the glTF Fox (bind pose, skipped without the data):
    autodiff against finite differences of the antialiased and of the supersampled image.
(c) The image loss of (b) along 20 random translation directions and 20 random rotation axes of
    the limb and the Fox, autodiff at the start against the central difference over one pixel
    of motion (the fraction within 15 %).  The L2 loss of a pixel image is not smooth on the
    pixel scale (each outline pixel's term is quadratic in where the edge crosses it), so the
    same test is also made of the supersampled image's loss (its slope over +-0.1 px against its
    own 1-px difference), and two checks that need no smoothness are added: autodiff against
    the supersampled loss's slope at the same point, and the mean of autodiff over the step (9
    points, Simpson's rule) against the difference, which holds exactly where the image is
    continuous and autodiff is its derivative.
(d) Cost: a batch of 8 coverage images of the limb at 256x192, rasterized alone and then
    antialiased (with and without a background), forward and reverse mode.

    python -m experiments.silhouette_gradients --quick --out out/silhouette_gradients
"""

from __future__ import annotations

import argparse
import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from experiments.common import DATA, machine, markdown_table, time_jitted, write_table
from jaxgfx import skin
from jaxgfx.camera import (
    Camera,
    camera_basis,
    focal_length,
    look_at,
    project,
    supersampled,
    yaw_pitch_roll_rotation,
)
from jaxgfx.raster import rasterize
from jaxgfx.silhouette import analytic_antialias, silhouette_edges

FOX = DATA / "rigs" / "fox.glb"
CREDIT = (
    "Fox: model by PixelMannen (CC0), rigging and animation by @tomkranis (CC-BY 4.0), glTF "
    "conversion by @AsoboStudio and @scurest."
)
SPHERE_RADIUS, SPHERE_DISTANCE = 0.8, 3.0
# Parameters of a scene's motion: translation (3), rotation vector (3) and log scale (1) of the
# mesh about its centre, then the camera's yaw, pitch and position (3).
N_PARAMS = 12
MOTIONS = {
    "translate x": 0,
    "translate y": 1,
    "translate z": 2,
    "rotate x": 3,
    "rotate y": 4,
    "rotate z": 5,
    "scale": 6,
    "camera yaw": 7,
    "camera pitch": 8,
    "camera x": 9,
}
DIRECTION_RTOL = 0.15  # (c): autodiff within 15 % of the central difference


@dataclasses.dataclass(frozen=True)
class Scene:
    """A mesh, its camera and the centre it rotates and scales about."""

    name: str
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) int32
    cam: Camera
    center: np.ndarray  # (3,)


def sphere_scene(width=96, height=72) -> Scene:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=SPHERE_RADIUS)
    cam = look_at([0.0, 0.0, -SPHERE_DISTANCE], [0.0, 0.0, 0.0], 60.0, width, height)
    return Scene(
        "sphere", mesh.vertices.astype(np.float32), mesh.faces.astype(np.int32), cam, np.zeros(3)
    )


def framed(name, vertices, faces, width, height, direction) -> Scene:
    """The mesh seen from ``direction`` at 1.6 times its size, 40 degree field of view."""
    lo, hi = vertices.min(0), vertices.max(0)
    center = 0.5 * (lo + hi)
    d = np.asarray(direction, np.float64)
    eye = center + 1.6 * float(np.linalg.norm(hi - lo)) * d / np.linalg.norm(d)
    cam = look_at(eye, center, 40.0, width, height, near=0.01)
    return Scene(name, vertices.astype(np.float32), faces.astype(np.int32), cam, center)


def limb_scene(width=128, height=96) -> Scene:
    arm = skin.demo_arm()
    pose = skin.demo_arm_pose(arm.rig, 1.0, 0.6)
    verts = np.asarray(skin.skin_exact(arm.rig, pose, arm.binding, None)[0])
    return framed("limb", verts, arm.faces, width, height, [1.0, 0.3, 0.5])


def fox_scene(width=128, height=96) -> Scene:
    fox = skin.load_gltf_skin(str(FOX))
    return framed("fox", np.asarray(fox.vertices), fox.faces, width, height, [1.0, 0.4, -0.6])


def moved(scene: Scene, p):
    """The camera and the vertices after motion ``p`` (N_PARAMS,)."""
    c = jnp.asarray(scene.center, jnp.float32)
    rel = (jnp.asarray(scene.vertices) - c) @ skin.axis_angle_to_matrix(p[3:6]).T
    verts = c + jnp.exp(p[6]) * rel + p[:3]
    cam = dataclasses.replace(
        scene.cam,
        rotation=yaw_pitch_roll_rotation(
            scene.cam.yaw + p[7], scene.cam.pitch + p[8], scene.cam.roll
        ),
        position=scene.cam.position + p[9:12],
    )
    return cam, verts


def antialiased(cam, verts, faces, edges):
    """(H, W) antialiased coverage."""
    out = rasterize(cam, verts, faces, jnp.ones((verts.shape[0], 1), jnp.float32))
    covered = (out.tri_id >= 0).astype(jnp.float32)[..., None]
    return analytic_antialias(cam, verts, faces, out, covered, edges=edges, background=0.0)[..., 0]


def supersampled_coverage(cam, verts, faces, n):
    """(H, W) fraction of ``n x n`` samples per pixel covered (an independent reference)."""
    big = supersampled(cam, (n, n))
    out = rasterize(big, verts, faces, jnp.ones((verts.shape[0], 1), jnp.float32))
    covered = (out.tri_id >= 0).astype(jnp.float32)
    return covered.reshape(cam.height, n, cam.width, n).mean((1, 3))


def image_sums(img, target):
    """Area (px^2), centroid x and y (px) and the L2 loss against ``target`` (px^2)."""
    h, w = img.shape
    xs = jnp.arange(w, dtype=jnp.float32) + 0.5
    ys = jnp.arange(h, dtype=jnp.float32) + 0.5
    area = jnp.sum(img)
    cx = jnp.sum(img * xs[None, :]) / area
    cy = jnp.sum(img * ys[:, None]) / area
    return jnp.stack([area, cx, cy, jnp.sum((img - target) ** 2)])


SUMS = ("area", "centroid x", "centroid y", "loss")


class Probe:
    """Jitted sums of one scene's antialiased and supersampled images, and their Jacobian.

    The loss's target image is an argument (set :attr:`target`), so one compile serves every
    target.
    """

    def __init__(self, scene: Scene, samples: int):
        self.scene = scene
        self.samples = samples
        faces = jnp.asarray(scene.faces)
        edges = jnp.asarray(silhouette_edges(scene.faces, scene.vertices))

        def aa(p):
            cam, verts = moved(scene, p)
            return antialiased(cam, verts, faces, edges)

        def ss(p):
            cam, verts = moved(scene, p)
            return supersampled_coverage(cam, verts, faces, samples)

        def screen(p):
            cam, verts = moved(scene, p)
            return project(cam, verts)[0]

        def raw(p):
            cam, verts = moved(scene, p)
            out = rasterize(cam, verts, faces, jnp.ones((verts.shape[0], 1), jnp.float32))
            return jnp.sum(out.tri_id >= 0)

        self.image = jax.jit(aa)
        self.ss_image = jax.jit(ss)
        self.raw_area = jax.jit(raw)
        # The sums from the jitted images: one compile of each renderer serves both.
        sums = jax.jit(image_sums)
        self._aa = lambda p, t: sums(self.image(p), t)
        self._ss = lambda p, t: sums(self.ss_image(p), t)
        self._jac = jax.jit(jax.jacrev(lambda p, t: image_sums(aa(p), t)))
        self._speed = jax.jit(lambda p, u: jax.jvp(screen, (p,), (u,))[1])
        self.target = jnp.zeros((scene.cam.height, scene.cam.width), jnp.float32)
        self.ss_target = self.target

    def aa(self, p):
        return self._aa(jnp.asarray(p, jnp.float32), self.target)

    def ss(self, p):
        return self._ss(jnp.asarray(p, jnp.float32), self.ss_target)

    def jac(self, p=None):
        p = jnp.zeros(N_PARAMS, jnp.float32) if p is None else jnp.asarray(p, jnp.float32)
        return np.asarray(self._jac(p, self.target), np.float64)

    def set_target(self, p):
        """The loss's target: the antialiased (and supersampled) image at motion ``p``."""
        self.target = self.image(jnp.asarray(p, jnp.float32))
        self.ss_target = self.ss_image(jnp.asarray(p, jnp.float32))

    def pixel_step(self, u) -> float:
        """The step along ``u`` that moves the fastest vertex by one pixel."""
        zero = jnp.zeros(N_PARAMS, jnp.float32)
        v = np.asarray(self._speed(zero, jnp.asarray(u, jnp.float32)))
        return 1.0 / float(np.linalg.norm(v, axis=-1).max())

    def central(self, fn, u, h):
        u = np.asarray(u, np.float32)
        return (np.asarray(fn(h * u), np.float64) - np.asarray(fn(-h * u), np.float64)) / (2 * h)


def unit(k):
    u = np.zeros(N_PARAMS, np.float32)
    u[k] = 1.0
    return u


def rel_err(a, b):
    return abs(a - b) / max(abs(b), 1e-12)


def exact_sphere_area(scene: Scene, s: float) -> float:
    """Exact projected area of the sphere mesh scaled by ``s``: the convex hull of its projected
    vertices, in float64 (the camera looks along +z from ``(0, 0, -d)``)."""
    f = float(focal_length(scene.cam))
    v = np.asarray(scene.vertices, np.float64) * s
    z = v[:, 2] + SPHERE_DISTANCE  # the camera looks along +z from (0, 0, -d)
    return float(ConvexHull(np.stack([f * v[:, 0] / z, f * v[:, 1] / z], 1)).volume)


def sphere_case(probe: Probe, sweep: int):
    """(a): A(s), dA/ds by every route, and the sweep's steps."""
    scene = probe.scene
    scale = unit(6)  # log scale: d/d(log s) = d/ds at s = 1
    probe.set_target(np.zeros(N_PARAMS))
    area_aa = float(probe.aa(0 * scale)[0])
    area_ss = float(probe.ss(0 * scale)[0])
    f = float(focal_length(scene.cam))
    r2, d2 = SPHERE_RADIUS**2, SPHERE_DISTANCE**2
    area_round = np.pi * f * f * r2 / (d2 - r2)
    ad = float(probe.jac()[0] @ scale)
    lo, hi = np.log(0.98) * scale, np.log(1.02) * scale  # s = 0.98 and 1.02
    fd = (float(probe.aa(hi)[0]) - float(probe.aa(lo)[0])) / 0.04
    fd_ss = (float(probe.ss(hi)[0]) - float(probe.ss(lo)[0])) / 0.04
    hull = [exact_sphere_area(scene, s) for s in (1.0, 0.98, 1.02)]
    hull_d = (hull[2] - hull[1]) / 0.04
    scales = np.linspace(0.99, 1.01, sweep)
    areas = np.array([float(probe.aa(np.log(s) * scale)[0]) for s in scales])
    raws = np.array([float(probe.raw_area(jnp.asarray(np.log(s) * scale))) for s in scales])
    exact = np.array([exact_sphere_area(scene, s) for s in scales])
    steps = np.diff(areas)
    row = {
        "A": area_aa,
        "A_supersampled": area_ss,
        "A_exact": hull[0],
        "A_round_sphere": float(area_round),
        "dA/ds": ad,
        "fd_2%": fd,
        "fd_2%_supersampled": fd_ss,
        "fd_2%_exact": hull_d,
        "2A": 2 * area_aa,
        "dA/ds_round_sphere": float(2 * area_round * d2 / (d2 - r2)),
        "vs_fd_%": 100 * rel_err(ad, fd),
        "vs_2A_%": 100 * rel_err(ad, 2 * area_aa),
        "vs_exact_%": 100 * rel_err(ad, hull_d),
        "A_vs_supersampled_%": 100 * rel_err(area_aa, area_ss),
        "sweep_mean_step": float(steps.mean()),
        "sweep_max_departure": float(np.abs(steps - steps.mean()).max()),
    }
    # The loss against a copy shifted by 2 px along x, moved along x.
    shift = 2.0 * SPHERE_DISTANCE / f
    probe.set_target(shift * unit(0))
    h = probe.pixel_step(unit(0))
    row["dloss/dx"] = float(probe.jac()[3, 0])
    row["dloss/dx_fd_1px"] = float(probe.central(probe.aa, unit(0), h)[3])
    return row, (scales, areas, raws, exact)


# Changes per 1-px step below these are treated as invariance (the row is left out): area in
# px^2, centroid in px, loss as a fraction of the loss itself.
FLOOR = {"area": 0.5, "centroid x": 0.005, "centroid y": 0.005, "loss": 0.01}


def motion_rows(probe: Probe, motions):
    """(b): autodiff vs the two central differences for each motion and sum, per 1-px step.

    Errors: area in % of the area the outline sweeps over the step (so that a motion that
    barely changes the area is not judged by a ratio of small numbers), centroids in px, the
    loss in % of its difference.
    """
    rows = []
    jac = probe.jac()
    loss0 = float(probe.aa(np.zeros(N_PARAMS))[3])
    for motion in motions:
        u = unit(MOTIONS[motion])
        h = probe.pixel_step(u)
        fd = probe.central(probe.aa, u, h) * h
        fd_ss = probe.central(probe.ss, u, h) * h
        ad = jac @ u * h
        swept = 0.5 * float(
            jnp.sum(
                jnp.abs(probe.ss_image(jnp.asarray(h * u)) - probe.ss_image(jnp.asarray(-h * u)))
            )
        )
        for k, what in enumerate(SUMS):
            floor = FLOOR[what] * (loss0 if what == "loss" else 1.0)
            if abs(fd[k]) < floor and abs(ad[k]) < floor:
                continue  # invariant under this motion (e.g. the sphere's area under a turn)
            if what == "area":
                scale, unit_ = swept / 100, "% of swept"
            elif what == "loss":
                scale, unit_ = abs(fd[k]) / 100, "%"
            else:
                scale, unit_ = 1.0, "px"
            ref = what != "loss"
            rows.append(
                {
                    "mesh": probe.scene.name,
                    "motion": motion,
                    "sum": what,
                    "autodiff": float(ad[k]),
                    "fd": float(fd[k]),
                    "fd_supersampled": float(fd_ss[k]) if ref else None,
                    "swept_px2": swept,
                    "err_vs_fd": float(abs(ad[k] - fd[k]) / scale),
                    "err_vs_supersampled": float(abs(ad[k] - fd_ss[k]) / scale) if ref else None,
                    "err_unit": unit_,
                }
            )
    return rows


SIMPSON = np.array([1, 4, 2, 4, 2, 4, 2, 4, 1]) / 24.0  # mean over [-1, 1], 8 intervals


def direction_rows(probe: Probe, count: int, key: int):
    """(c): the loss along random translation directions and rotation axes."""
    rng = np.random.default_rng(key)
    rows = []
    for kind, sl in (("translation", slice(0, 3)), ("rotation", slice(3, 6))):
        errs = {k: [] for k in ("ad_fd", "ss_local_ss_fd", "ad_ss_local", "mean_ad_fd")}
        for _ in range(count):
            u = np.zeros(N_PARAMS, np.float32)
            d = rng.normal(size=3)
            u[sl] = d / np.linalg.norm(d)
            h = probe.pixel_step(u)
            fd = probe.central(probe.aa, u, h)[3]
            ads = [float(probe.jac(x * h * u)[3] @ u) for x in np.linspace(-1, 1, 9)]
            ss_fd = probe.central(probe.ss, u, h)[3]
            ss_local = probe.central(probe.ss, u, 0.1 * h)[3]
            errs["ad_fd"].append(rel_err(ads[4], fd))
            errs["ss_local_ss_fd"].append(rel_err(ss_local, ss_fd))
            errs["ad_ss_local"].append(rel_err(ads[4], ss_local))
            errs["mean_ad_fd"].append(rel_err(float(SIMPSON @ ads), fd))
        row = {"mesh": probe.scene.name, "motion": kind, "directions": count}
        for k, e in errs.items():
            e = np.asarray(e)
            row[f"{k}_within_15%"] = float(np.mean(e <= DIRECTION_RTOL))
            row[f"{k}_median_%"] = float(100 * np.median(e))
        rows.append(row)
    return rows


def cost_rows(scene: Scene, batch: int = 8, repeats: int = 10):
    """(d): wall time of a batch of coverage images (vmap), forward and reverse mode."""
    faces = jnp.asarray(scene.faces)
    edges = jnp.asarray(silhouette_edges(scene.faces, scene.vertices))
    verts = jnp.stack([jnp.asarray(scene.vertices) + 0.002 * i for i in range(batch)])
    ones = jnp.ones((scene.vertices.shape[0], 1), jnp.float32)

    def raw(v):
        return (rasterize(scene.cam, v, faces, ones).tri_id >= 0).astype(jnp.float32)

    def smooth(background):
        def image(v):
            out = rasterize(scene.cam, v, faces, ones)
            cov = (out.tri_id >= 0).astype(jnp.float32)[..., None]
            aa = analytic_antialias(
                scene.cam, v, faces, out, cov, edges=edges, background=background
            )
            return aa[..., 0]

        return image

    rows = []
    for name, image in (
        ("rasterize (coverage)", raw),
        ("+ analytic_antialias", smooth(None)),
        ("+ analytic_antialias, background 0", smooth(0.0)),
    ):
        fwd = jax.jit(jax.vmap(image))
        grad = jax.jit(jax.vmap(jax.grad(lambda v, image=image: jnp.sum(image(v) ** 2))))
        _, t_fwd, _ = time_jitted(fwd, verts, repeats=repeats)
        _, t_grad, _ = time_jitted(grad, verts, repeats=repeats)
        rows.append(
            {
                "pass": name,
                "frames": f"{batch} x {scene.cam.width}x{scene.cam.height}",
                "forward_ms": 1e3 * t_fwd,
                "reverse_ms": 1e3 * t_grad,
            }
        )
    return rows


def target_motion(scene: Scene, pixels: float):
    """A displaced copy for the loss: ``pixels`` across the view and a 0.02 rad turn."""
    z = float(np.linalg.norm(np.asarray(scene.cam.position) - scene.center))
    world = pixels * z / float(focal_length(scene.cam))
    p = np.zeros(N_PARAMS, np.float32)
    p[:3] = world * np.asarray(camera_basis(scene.cam)[0])
    p[4] = 0.02
    return jnp.asarray(p)


def plot(path, sweep, scene_images):
    """The sphere's area step by step over the sweep and its error against the exact area;
    per scene the antialiased coverage and its difference from the supersampled one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxgfx.io import atomic_write

    scales, areas, raws, exact = sweep
    n = 1 + len(scene_images)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 7.0), squeeze=False)
    mid = 0.5 * (scales[1:] + scales[:-1])
    ax = axes[0, 0]
    ax.plot(mid, np.diff(raws), ".-", ms=3, color="0.6", label="z-buffer")
    ax.plot(mid, np.diff(areas), ".-", ms=3, label="antialiased")
    ax.plot(mid, np.diff(exact), "k--", lw=1, label="exact")
    ax.set_xlabel("scale s")
    ax.set_ylabel("step of the area A(s), px^2")
    ax.set_title(f"sphere: A(s) at {len(scales)} scales, step by step", fontsize=9)
    ax.legend(fontsize=7)
    ax = axes[1, 0]
    ax.plot(scales, raws - exact, ".-", ms=3, color="0.6", label="z-buffer")
    ax.plot(scales, areas - exact, ".-", ms=3, label="antialiased")
    ax.set_xlabel("scale s")
    ax.set_ylabel("A(s) - exact, px^2")
    ax.legend(fontsize=7)
    for c, (name, aa, ss) in enumerate(scene_images, start=1):
        ys, xs = np.nonzero((aa > 0) | (ss > 0))
        crop = np.s_[max(ys.min() - 2, 0) : ys.max() + 3, max(xs.min() - 2, 0) : xs.max() + 3]
        axes[0, c].imshow(aa[crop], cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        axes[0, c].set_title(f"{name}: antialiased coverage", fontsize=9)
        im = axes[1, c].imshow(
            (aa - ss)[crop], cmap="RdBu", vmin=-0.5, vmax=0.5, interpolation="nearest"
        )
        axes[1, c].set_title(f"{name}: antialiased - supersampled", fontsize=9)
        fig.colorbar(im, ax=axes[1, c], fraction=0.046)
        for a in axes[:, c]:
            a.axis("off")
    fig.tight_layout()
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="the sphere only, 8x8 samples (smoke test)"
    )
    ap.add_argument("--out", default=None, help="folder for the tables (.md/.json) and figure")
    ap.add_argument("--samples", type=int, default=None, help="supersampling per axis (16)")
    ap.add_argument("--directions", type=int, default=20, help="random directions in (c)")
    args = ap.parse_args(argv)
    samples = args.samples or (8 if args.quick else 16)
    print(machine())
    scenes = [sphere_scene()]
    if not args.quick:
        scenes.append(limb_scene())
        if FOX.exists():
            scenes.append(fox_scene())
        else:
            print(f"fox skipped: {FOX} is absent (the glTF sample Fox)")
    motions = list(MOTIONS) if not args.quick else ["scale"]
    rows, dir_rows, images = [], [], []
    sphere = sweep = None
    for scene in scenes:
        probe = Probe(scene, samples)
        if scene.name == "sphere":
            # quick: 11 scales (each is two frames); (c) below takes the time saved
            sphere, sweep = sphere_case(probe, 11 if args.quick else 41)
            print(markdown_table([sphere], list(sphere)), flush=True)
        probe.set_target(target_motion(scene, 1.5))
        rows += motion_rows(probe, motions)
        if scene.name != "sphere":
            dir_rows += direction_rows(probe, args.directions, key=1)
        elif args.quick:  # quick: (c) runs on the sphere's programs, one direction each
            dir_rows += direction_rows(probe, 1, key=1)
        zero = jnp.zeros(N_PARAMS, jnp.float32)
        aa = np.asarray(probe.image(zero))
        ss = np.asarray(probe.ss_image(zero))  # the jitted reference (sphere_case compiled it)
        images.append((scene.name, aa, ss))
        print(f"{scene.name}: area antialiased {aa.sum():.2f}, supersampled {ss.sum():.2f}")
    assert sphere is not None and sweep is not None
    md = [
        "(a) sphere, 96x72: area (px^2) and dA/ds by autodiff, by central differences over "
        "s = 1 +- 2 % (of the antialiased, the supersampled and the exact area), 2A and the "
        f"round sphere's closed form; the sweep: A(s) at {len(sweep[0])} scales in [0.99, 1.01], "
        "its mean "
        "step and the largest departure from it (px^2); the loss against a copy 2 px to the "
        "side, along x\n\n",
        markdown_table([sphere], list(sphere)),
        "\n\n(b) sums of the image, change per 1-px step: autodiff vs central differences of "
        "the antialiased and of the supersampled image (sums a motion leaves unchanged are "
        "left out); errors: area in % of the area the outline sweeps over the step, centroids "
        "in px, the loss in % of its difference\n\n",
        markdown_table(rows, list(rows[0])),
    ]
    if dir_rows:
        md += [
            "\n\n(c) image loss along random directions: the fraction of directions within 15 "
            "% and the median error of autodiff at the start against the 1-px central "
            "difference (ad_fd); the same test of the supersampled loss, its +-0.1 px slope "
            "against its 1-px difference (ss_local_ss_fd); autodiff against the supersampled "
            "loss's slope (ad_ss_local); the mean of autodiff over the step against the "
            "difference (mean_ad_fd)\n\n"
        ]
        md += [markdown_table(dir_rows, list(dir_rows[0]))]
    cost = [] if args.quick else cost_rows(limb_scene(256, 192))
    if cost:
        md += [
            "\n\n(d) cost: a batch of coverage images of the limb (vmap, median of 10 calls), "
            "and the reverse-mode gradient of their sum of squares w.r.t. the vertices\n\n",
            markdown_table(cost, list(cost[0])),
        ]
    footer = (
        f"\n\nSupersampled: {samples}x{samples} samples per pixel.  Steps of (b) and (c): the "
        "motion that moves the fastest vertex by 1 px; loss: sum of squares against the "
        "antialiased image of a copy moved 1.5 px across the view and turned 0.02 rad.\n"
        f"{CREDIT}\nmachine: {machine()}"
    )
    text = "".join(md) + footer
    print(text)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        write_table(
            args.out,
            "Silhouette gradients",
            text,
            {
                "sphere": sphere,
                "sweep": {
                    "scales": sweep[0].tolist(),
                    "areas": sweep[1].tolist(),
                    "z_buffer_areas": sweep[2].tolist(),
                    "exact_areas": sweep[3].tolist(),
                },
                "motions": rows,
                "directions": dir_rows,
                "cost": cost,
                "samples": samples,
            },
        )
        plot(os.path.join(args.out, "silhouette_gradients.png"), sweep, images)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
