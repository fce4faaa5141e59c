"""``jaxgfx skin``: pose the demo arm with spline skinning (+ style), LBS or DQS and render it."""

from __future__ import annotations

import math
import time

from jaxgfx.cli.args import PIXEL_BYTES, bounded_float, check_image, check_out_dir, parse_size

__all__ = ["register", "run"]

# One full turn either way: enough for any pose, and far from float32 trouble.
_ANGLE = bounded_float(-360.0, 360.0)


def register(subparsers) -> None:
    """Add the ``skin`` subcommand to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "skin",
        help="render the demo arm bent/twisted with spline skinning, LBS or DQS (thesis ch. 5)",
    )
    p.add_argument(
        "--method",
        choices=("spline", "lbs", "dqs"),
        default="spline",
        help="spline skinning (thesis), linear blend or dual quaternion skinning",
    )
    p.add_argument(
        "--style",
        choices=("none", "muscle"),
        default="muscle",
        help="deformation style (spline only)",
    )
    p.add_argument("--bend", type=_ANGLE, default=90.0, help="elbow bend in degrees, |bend| <= 360")
    p.add_argument("--twist", type=_ANGLE, default=0.0, help="twist in degrees, |twist| <= 360")
    p.add_argument("--size", type=parse_size, default=(320, 320), help="WxH (default 320x320)")
    p.add_argument("--out", default="skin_out", help="output directory")
    p.set_defaults(func=run)


def run(args) -> int:
    """Handler: writes ``skin.png`` and prints the deformation time."""
    out_dir = check_out_dir("--out", args.out)
    check_image(args.size, PIXEL_BYTES)

    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxgfx import skin
    from jaxgfx.camera import look_at
    from jaxgfx.compose import lambert
    from jaxgfx.io import save_png
    from jaxgfx.raster import rasterize

    w, h = args.size
    arm = skin.demo_arm()
    rig, binding, faces = arm.rig, arm.binding, arm.faces
    pose = skin.demo_arm_pose(rig, math.radians(args.bend), math.radians(args.twist))
    style = skin.muscle_style() if args.style == "muscle" else None
    styles = "both" if (style is not None and args.method == "spline") else "none"

    @jax.jit
    def deform(pose):
        if args.method == "spline":
            return skin.skin_exact(rig, pose, binding, style, styles=styles)
        t = skin.bone_transforms(rig, pose)
        joints, weights = skin.bone_weights_from_binding(binding, blend_width=0.5)
        fn = skin.linear_blend_skinning if args.method == "lbs" else skin.dual_quaternion_skinning
        return fn(t, binding.rest, binding.rest_normal, joints, weights)

    t0 = time.perf_counter()
    pos, nrm = jax.block_until_ready(deform(pose))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    pos, nrm = jax.block_until_ready(deform(pose))
    steady = time.perf_counter() - t0
    centre = np.asarray(pos).mean(0)
    cam = look_at(
        centre + np.array([4.0, 0.6, 0.0]), centre, fov=45.0, width=w, height=h, near=0.05, far=50.0
    )
    out = jax.jit(rasterize)(cam, pos, jnp.asarray(faces), nrm)
    albedo = jnp.broadcast_to(jnp.array([0.85, 0.6, 0.45]), out.color.shape)
    img = jnp.where((out.tri_id >= 0)[..., None], lambert(out.color, albedo), 1.0)
    path = out_dir / "skin.png"
    save_png(path, np.asarray(img))
    print(
        f"{args.method} (style {styles}): {len(arm.vertices)} vertices, first call {first:.3f} s, "
        f"steady {steady * 1e3:.3f} ms; wrote {path}"
    )
    return 0
