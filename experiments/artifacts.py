"""Fig. 5.27 as numbers: candy-wrapper and collapse of LBS, bulging of DQS, spline skinning.

A closed cylinder (radius 0.25, length 2) on one spline is twisted by 180° and, separately, bent
by 90° at its joint.  LBS and DQS use the same skeleton (two bones, :func:`skin.bone_transforms`)
with weights blended over a quarter of the length around the joint.  We measure the area of the
cross-section ring at the joint and the enclosed volume, both relative to the rest pose
(1.0 = preserved), and render the six results side by side with the rasterizer.

    python -m experiments.artifacts --quick --out out/artifacts
"""

from __future__ import annotations

import argparse
import math
import os

import jax
import jax.numpy as jnp
import numpy as np

from experiments.common import cylinder, machine, markdown_table, write_table
from jaxgfx import skin

RADIUS = 0.25


def ring_area(points: np.ndarray) -> float:
    """Area of a closed (nearly planar) 3D polygon: half the norm of its vector area."""
    p = np.asarray(points, np.float64)
    return 0.5 * float(np.linalg.norm(np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)))


def volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume of a closed, outward-oriented triangle mesh (divergence theorem)."""
    v = np.asarray(vertices, np.float64)[faces]
    return float(np.einsum("fi,fi->f", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="coarser mesh, smaller images")
    ap.add_argument("--out", default=None, help="write the table (Markdown, JSON) and figures here")
    args = ap.parse_args(argv)
    print(machine())
    n_around, n_along = (24, 41) if args.quick else (48, 81)
    v, n, faces = cylinder(n_around, n_along, RADIUS, 2.0, caps=True)
    rig = skin.make_rig(
        np.array([[[0, 0, 0], [0, 0, 1], [0, 0, 2]]], np.float32),
        stiffness=4.0,
        reference_normal=[[1.0, 0.0, 0.0]],
    )
    binding = skin.bind_mesh(
        rig, v, np.zeros((len(v), 1), np.int32), np.ones((len(v), 1)), normals=n
    )
    joints, weights = skin.bone_weights_from_binding(binding, blend_width=0.5)
    ring = (n_along // 2) * n_around + np.arange(n_around)  # the ring at z = 1 (x = 0.5)
    rest_area, rest_volume = ring_area(v[ring]), volume(v, faces)

    def pose(bend, twist):
        rot = skin.axis_angle_to_matrix(jnp.array([bend, 0.0, 0.0]))
        return skin.forward_kinematics(
            rig, jnp.eye(3)[None], rot[None], twist=jnp.array([twist], jnp.float32)
        )

    @jax.jit
    def deform(p):
        t = skin.bone_transforms(rig, p)
        lbs = skin.linear_blend_skinning(t, binding.rest, binding.rest_normal, joints, weights)
        dqs = skin.dual_quaternion_skinning(t, binding.rest, binding.rest_normal, joints, weights)
        spl = skin.skin_exact(rig, p, binding)
        return {"LBS (SSD)": lbs, "DQS": dqs, "spline skinning": spl}

    poses = {"180° twist": pose(0.0, math.pi), "90° bend": pose(math.pi / 2, 0.0)}
    rows, results = [], {}
    for pname, p in poses.items():
        out = deform(p)
        for method in ("LBS (SSD)", "DQS", "spline skinning"):
            pos, nrm = out[method]
            pos = np.asarray(pos)
            results[(pname, method)] = (pos, np.asarray(nrm))
            rows.append(
                {
                    "pose": pname,
                    "method": method,
                    "joint_area_rel": ring_area(pos[ring]) / rest_area,
                    "volume_rel": volume(pos, faces) / rest_volume,
                    "min_joint_radius_rel": float(
                        np.min(np.linalg.norm(pos[ring] - pos[ring].mean(0), axis=1)) / RADIUS
                    ),
                }
            )
    cols = ["pose", "method", "joint_area_rel", "volume_rel", "min_joint_radius_rel"]
    md = markdown_table(rows, cols)
    footer = (
        f"\n\nCylinder radius {RADIUS}, length 2, {len(v)} vertices; LBS/DQS weights blend over "
        f"x in [0.25, 0.75].  1.0 = as at rest.  For the bend the ring's area is measured on the "
        f"ring polygon (vector area).\nmachine: {machine()}"
    )
    print(md + footer)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        write_table(
            args.out,
            "Deformation artifacts (Fig. 5.27)",
            md + footer,
            {"machine": machine(), "rows": rows},
        )
        try:
            from jaxgfx.camera import look_at
            from jaxgfx.compose import lambert
            from jaxgfx.io import save_png
            from jaxgfx.raster import rasterize
        except ImportError as err:  # the rasterizer is a separate module of the package
            print(f"no images: {err}")
            return 0
        wh = (160, 160) if args.quick else (256, 256)
        raster = jax.jit(rasterize)
        # stripes along the rest angle make the twist visible
        band = (np.sin(4 * np.arctan2(v[:, 1], v[:, 0])) > 0)[:, None]
        stripes = jnp.asarray(np.where(band, [0.85, 0.8, 0.6], [0.55, 0.35, 0.25]), jnp.float32)
        tiles = []
        for pname in poses:
            row = []
            for method in ("LBS (SSD)", "DQS", "spline skinning"):
                pos, nrm = results[(pname, method)]
                centre = pos.mean(0)
                cam = look_at(
                    centre + np.array([3.2, 0.4, 0.0]),
                    centre,
                    fov=45.0,
                    width=wh[0],
                    height=wh[1],
                    near=0.05,
                    far=50.0,
                )
                attrs = jnp.concatenate([jnp.asarray(nrm), stripes], axis=1)
                o = raster(cam, jnp.asarray(pos), jnp.asarray(faces), attrs)
                shaded = lambert(o.color[..., :3], o.color[..., 3:])
                img = jnp.where((o.tri_id >= 0)[..., None], shaded, 1.0)
                row.append(np.asarray(img))
            tiles.append(np.concatenate(row, 1))
        save_png(os.path.join(args.out, "artifacts.png"), np.concatenate(tiles, 0))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
