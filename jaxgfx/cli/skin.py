"""``jaxgfx skin``: skin the demo arm or a glTF rig with spline skinning (+ style), LBS or DQS.

Without ``--rig`` the demo arm is posed by ``--bend`` and ``--twist``.  With ``--rig file.glb``
the character is posed by its first animation clip at ``--time`` (bind pose by default): LBS and
DQS use every joint of the file; ``spline`` replaces the ``--chain`` of three joints (default
the tail, when the rig has b_Tail01-03) by one spline carrying the style (thesis 5.9.3) and
skins the other joints by LBS.  A ``--style`` other than ``none`` needs ``--method spline``
(LBS and DQS have no styles); left out it means ``muscle`` for spline, ``none`` otherwise.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np

from jaxgfx.cli.args import (
    PIXEL_BYTES,
    CliError,
    bounded_float,
    check_image,
    check_in_file,
    check_out_dir,
    check_out_file,
    input_errors,
    parse_size,
    writing,
)
from jaxgfx.cli.framing import ARM_VIEW, CHARACTER_VIEW, framed_camera, warn_if_unseen

__all__ = ["register", "run"]

FOV = 45.0
"""Vertical field of view of the skinned body's view, degrees."""

# One full turn either way: enough for any pose, and far from float32 trouble.
_ANGLE = bounded_float(-360.0, 360.0)
_TAIL = ("b_Tail01", "b_Tail02", "b_Tail03")  # skin.TAIL_JOINTS (not imported: no jax at parse)


def _chain_names(text: str) -> tuple[str, ...]:
    return tuple(n.strip() for n in text.split(",") if n.strip())


def register(subparsers) -> None:
    """Add the ``skin`` subcommand to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "skin",
        help="skin the demo arm or a glTF rig with spline skinning, LBS or DQS (thesis ch. 5)",
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
        default=None,
        help="deformation style, spline only (default: muscle for spline, none otherwise)",
    )
    p.add_argument(
        "--bend",
        type=_ANGLE,
        default=None,
        help="demo arm: elbow bend in degrees, |bend| <= 360 (default 90)",
    )
    p.add_argument(
        "--twist",
        type=_ANGLE,
        default=None,
        help="demo arm: twist in degrees, |twist| <= 360 (default 0)",
    )
    p.add_argument("--rig", default=None, help="a skinned glTF character (.glb) instead of the arm")
    p.add_argument(
        "--time",
        type=bounded_float(0.0, math.inf),
        default=None,
        help="with --rig: seconds into its animation, within the clip (default: bind pose)",
    )
    p.add_argument(
        "--chain",
        type=_chain_names,
        default=None,
        help="with --rig and spline: three joint names, root first, comma-separated, made one "
        "spline (default: b_Tail01,b_Tail02,b_Tail03)",
    )
    p.add_argument("--size", type=parse_size, default=(320, 320), help="WxH (default 320x320)")
    p.add_argument(
        "--out", default="skin_out", help="output .png, or a directory (writes skin.png in it)"
    )
    p.add_argument(
        "--depth",
        default=None,
        help="also write camera-space depth (+inf = empty) to this .npy",
    )
    p.set_defaults(func=run)


def _check_args(args) -> str:
    """Usage errors before any work; returns the style name."""
    style = args.style or ("muscle" if args.method == "spline" else "none")
    if style != "none" and args.method != "spline":
        raise CliError(f"--style {style}: --method {args.method} has no deformation styles")
    if args.rig is None:
        for opt in ("time", "chain"):
            if getattr(args, opt) is not None:
                raise CliError(f"--{opt} needs --rig (the demo arm has no animation or joints)")
    else:
        for opt in ("bend", "twist"):
            if getattr(args, opt) is not None:
                raise CliError(f"--{opt} poses the demo arm; with --rig use --time")
        if args.chain is not None and args.method != "spline":
            raise CliError(f"--chain: --method {args.method} skins every joint, no spline")
        if not os.path.exists(args.rig):
            raise CliError(f"--rig: no such file {args.rig!r}")
        check_in_file("--rig", args.rig, "a binary glTF (.glb)")
        if not args.rig.lower().endswith(".glb"):
            raise CliError(f"--rig {args.rig!r}: expected a binary glTF (.glb)")
    return style


def _rig_mesh(args, style_name: str):
    """Posed positions, normals and faces of the glTF rig (host NumPy and jitted skinning)."""
    import jax

    from jaxgfx import skin

    with input_errors("--rig"):
        gskin = skin.load_gltf_skin(args.rig)
    if args.time is not None and gskin.duration <= 0:
        raise CliError(f"--time {args.time:g}: {args.rig} has no animation")
    if args.time is not None and args.time > gskin.duration:
        raise CliError(
            f"--time {args.time:g} is outside the clip, which lasts [0, {gskin.duration:g}] s"
        )
    if args.method == "spline":
        names = args.chain
        if names is None:
            if not set(_TAIL) <= set(gskin.joint_names):
                raise CliError(f"--chain: {args.rig} has no {','.join(_TAIL)}; name three joints")
            names = _TAIL
        try:
            chain = skin.gltf_spline_chain(gskin, names)
        except ValueError as exc:
            msg = str(exc).removeprefix("chain: ")
            raise CliError(f"--chain {','.join(names)}: {msg}") from None
        pose = skin.gltf_pose(gskin, chain, args.time)
        style = skin.muscle_style() if style_name == "muscle" else None
        fn = jax.jit(skin.skin_gltf_chain)
        inputs: tuple = (chain, pose, style)
    else:
        local = gskin.rest_trs if args.time is None else skin.sample_animation(gskin, args.time)
        mats = skin.joint_matrices(gskin, local)
        lbs_or_dqs = (
            skin.linear_blend_skinning if args.method == "lbs" else skin.dual_quaternion_skinning
        )
        fn = jax.jit(lbs_or_dqs)
        inputs = (mats, gskin.vertices, gskin.normals, gskin.joints, gskin.weights)
    return fn, inputs, gskin.faces


def _arm_mesh(args, style_name: str):
    import jax

    from jaxgfx import skin

    arm = skin.demo_arm()
    rig, binding = arm.rig, arm.binding
    bend = 90.0 if args.bend is None else args.bend
    twist = 0.0 if args.twist is None else args.twist
    pose = skin.demo_arm_pose(rig, math.radians(bend), math.radians(twist))  # takes radians
    style = skin.muscle_style() if style_name == "muscle" else None
    styles = "none" if style is None else "both"

    @jax.jit
    def deform(pose):
        if args.method == "spline":
            return skin.skin_exact(rig, pose, binding, style, styles=styles)
        t = skin.bone_transforms(rig, pose)
        joints, weights = skin.bone_weights_from_binding(binding, blend_width=0.5)
        fn = skin.linear_blend_skinning if args.method == "lbs" else skin.dual_quaternion_skinning
        return fn(t, binding.rest, binding.rest_normal, joints, weights)

    return deform, (pose,), arm.faces


def run(args) -> int:
    """Handler: writes the image (and ``--depth``) and prints the deformation time."""
    if Path(args.out).suffix.lower() == ".png":  # a file, as the other commands' --out
        path = check_out_file("--out", args.out, (".png",))
    else:
        path = check_out_dir("--out", args.out) / "skin.png"
    depth_path = check_out_file("--depth", args.depth, (".npy",)) if args.depth else None
    check_image(args.size, PIXEL_BYTES)
    style_name = _check_args(args)

    import jax
    import jax.numpy as jnp

    from jaxgfx.compose import lambert
    from jaxgfx.io import save_npy, save_png
    from jaxgfx.raster import rasterize

    deform, inputs, faces = (_rig_mesh if args.rig else _arm_mesh)(args, style_name)
    t0 = time.perf_counter()
    pos, nrm = jax.block_until_ready(deform(*inputs))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    pos, nrm = jax.block_until_ready(deform(*inputs))
    steady = time.perf_counter() - t0
    p = np.asarray(pos)
    # Every vertex of the posed body inside the frame: three-quarter from the side for a
    # glTF character (they face +z), from the side for the arm (its bend shows).
    cam = framed_camera(p, CHARACTER_VIEW if args.rig else ARM_VIEW, FOV, args.size)
    out = jax.jit(rasterize)(cam, pos, jnp.asarray(faces), nrm)
    albedo = jnp.broadcast_to(jnp.array([0.85, 0.6, 0.45]), out.color.shape)
    img = jnp.where((out.tri_id >= 0)[..., None], lambert(out.color, albedo), 1.0)
    with writing("--out", path):
        save_png(path, np.asarray(img))
    depth = np.asarray(out.depth)
    if depth_path is not None:
        with writing("--depth", depth_path):
            save_npy(depth_path, depth)
    what = args.rig or "demo arm"
    warn_if_unseen("skin", cam, p, int(np.isfinite(depth).sum()), repr(what), faces=faces)
    print(
        f"{args.method} (style {style_name}) of {what}: {len(p)} vertices, first call "
        f"{first:.3f} s, steady {steady * 1e3:.3f} ms; wrote {path}"
    )
    return 0
