"""``jaxgfx render`` and ``jaxgfx sweep``: a mesh drawn by the rasterizer, one view or an orbit.

A ``.glb`` with a skinned mesh (a glTF character such as the sample Fox) is drawn as glTF
means it: the skinned mesh posed by its joints (the bind pose, or ``--time`` seconds into its
first animation clip; linear blend skinning), plus the file's other meshes at their node
transforms.  trimesh, which reads every other file, ignores skins and draws the character at
its mesh node's transform (for the Fox: a dot beside its stand).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

from jaxgfx.cli.args import (
    PIXEL_BYTES,
    CliError,
    add_up_argument,
    bounded_float,
    check_image,
    check_memory,
    check_out_dir,
    check_out_file,
    parse_floats,
    parse_fov,
    parse_size,
    positive_int,
)

CHARACTER_COLOR = (0.85, 0.5, 0.25)
"""The skinned mesh of a ``.glb`` is drawn in this colour (textures are not read)."""

__all__ = ["register", "run_render", "run_sweep", "contact_sheet"]


def _bounds(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius (half the diagonal) of the bounding box."""
    lo, hi = vertices.min(0), vertices.max(0)
    return 0.5 * (lo + hi), float(np.linalg.norm(hi - lo)) * 0.5 + 1e-6


def _framing(vertices: np.ndarray, fov: float) -> tuple[np.ndarray, float]:
    """Centre of the bounding box and the distance that frames it at ``fov`` degrees."""
    center, radius = _bounds(vertices)
    return center, radius / math.sin(math.radians(fov) / 2) * 1.1


# Default view directions (from the target to the eye): meshes from the front and a little
# above; characters three-quarter from the side (glTF characters face +z, so the front view
# hides their length).
_VIEW = (0.0, 0.35, 1.0)
_CHARACTER_VIEW = (0.8, 0.4, 0.6)


def _camera_for(vertices: np.ndarray, args: argparse.Namespace, view=_VIEW):
    from jaxgfx.camera import camera_from_degrees, look_at

    w, h = args.size
    if args.camera is not None:
        _, radius = _bounds(vertices)
        x, y, z, yaw, pitch = args.camera
        return camera_from_degrees(
            [x, y, z], yaw, pitch, 0.0, args.fov, w, h, radius * 1e-3, radius * 1e3
        )
    center, dist = _framing(vertices, args.fov)
    eye = center + dist * np.asarray(view) / np.linalg.norm(view)
    return look_at(eye, center, args.fov, w, h, dist * 1e-3, dist * 10)


def _is_skinned_glb(path: str) -> bool:
    """True for a readable ``.glb`` with a skinned mesh node (read with pygltflib)."""
    if not path.lower().endswith(".glb") or not os.path.isfile(path):
        return False
    import pygltflib

    try:
        doc = pygltflib.GLTF2().load(path)
    except Exception:  # not readable as glTF: trimesh reports the error
        return False
    return doc is not None and any(n.skin is not None and n.mesh is not None for n in doc.nodes)


def _skinned_scene(args: argparse.Namespace):
    """The posed character and the file's other meshes as one :class:`MeshPass` (+ info)."""
    from jaxgfx import skin
    from jaxgfx.io import up_rotation
    from jaxgfx.scene import merge_mesh_passes, mesh_pass

    gskin = skin.load_gltf_skin(args.mesh)
    t = getattr(args, "time", None)  # sweep has no --time: the bind pose
    if t is None:
        local = gskin.rest_trs
    elif gskin.duration <= 0:
        raise CliError(f"--time {t:g}: {args.mesh} has no animation")
    elif not 0.0 <= t <= gskin.duration:
        raise CliError(f"--time {t:g} is outside the clip, which lasts [0, {gskin.duration:g}] s")
    else:
        local = skin.sample_animation(gskin, t)
    mats = skin.joint_matrices(gskin, local)
    pos, nrm = skin.linear_blend_skinning(
        mats, gskin.vertices, gskin.normals, gskin.joints, gskin.weights
    )
    rot = up_rotation(args.up).astype(np.float32)
    color = np.tile(np.asarray(CHARACTER_COLOR, np.float32), (len(gskin.vertices), 1))
    passes = [mesh_pass(np.asarray(pos) @ rot.T, gskin.faces, color, np.asarray(nrm) @ rot.T)]
    for m in skin.load_gltf_meshes(args.mesh):
        passes.append(mesh_pass(m.vertices @ rot.T, m.faces, m.colors))
    info = dict(skinned_vertices=len(gskin.vertices), time=t, props=len(passes) - 1)
    return merge_mesh_passes(passes), info


def run_render(args: argparse.Namespace) -> int:
    """Renders one view of a mesh; writes the PNG (and depth) and prints one JSON line."""
    out = check_out_file("--out", args.out, (".png",))
    depth = check_out_file("--depth", args.depth, (".npy",)) if args.depth else None
    check_image(args.size, PIXEL_BYTES)
    skinned = _is_skinned_glb(args.mesh)
    if args.time is not None and not skinned:
        raise CliError(f"--time applies to a .glb with a skinned mesh, not {args.mesh}")

    import jax

    from jaxgfx.compose import background, composite
    from jaxgfx.io import load_mesh, mesh_arrays, save_npy, save_png
    from jaxgfx.scene import mesh_pass, render_mesh_pass

    info: dict = {}
    if skinned:
        mp, info = _skinned_scene(args)
    else:
        mp = mesh_pass(*mesh_arrays(load_mesh(args.mesh, up=args.up)))
    v, f = np.asarray(mp.vertices), np.asarray(mp.faces)
    cam = _camera_for(v, args, _CHARACTER_VIEW if skinned else _VIEW)
    fn = jax.jit(
        lambda cam, mp: composite(
            [background(cam), render_mesh_pass(cam, mp, cull_backfaces=args.cull)]
        )
    )
    t0 = time.perf_counter()
    frame = jax.block_until_ready(fn(cam, mp))
    dt = time.perf_counter() - t0
    save_png(out, frame.color)
    if depth is not None:
        save_npy(depth, np.asarray(frame.depth))
    cov = float(np.isfinite(np.asarray(frame.depth)).mean())
    summary = dict(out=str(args.out), triangles=len(f), seconds=round(dt, 3), coverage=cov)
    print(json.dumps({**summary, **info}))
    return 0


def contact_sheet(images: np.ndarray, cols: int) -> np.ndarray:
    """Tiles (N, H, W, 3) uint8 images into one grid image."""
    n, h, w, ch = images.shape
    rows = -(-n // cols)
    sheet = np.zeros((rows * h, cols * w, ch), images.dtype)
    for i in range(n):
        r, c = divmod(i, cols)
        sheet[r * h : (r + 1) * h, c * w : (c + 1) * w] = images[i]
    return sheet


def _sweep_devices(wanted: int | None) -> list:
    """The first ``wanted`` JAX devices (all when None); too many is a usage error."""
    import jax

    devs = jax.devices()
    if wanted is None:
        return devs
    if wanted > len(devs):
        flags = os.environ.get("XLA_FLAGS", "")
        raise CliError(
            f"--devices {wanted}: JAX has {len(devs)} {devs[0].platform} device(s)"
            + (f" (XLA_FLAGS={flags!r} sets the host device count)" if flags else "")
        )
    return devs[:wanted]


def run_sweep(args: argparse.Namespace) -> int:
    """Orbits ``--n`` cameras around a mesh, chunk by chunk (resumable); writes frames + sheet."""
    from jaxgfx.camera import orbit_cameras
    from jaxgfx.compose import background, composite, to_uint8
    from jaxgfx.io import load_mesh, mesh_arrays, save_png
    from jaxgfx.scene import mesh_pass, render_mesh_pass
    from jaxgfx.sweep import SweepMismatch, load_sweep, run_sweep

    if args.n <= 0:
        raise CliError(f"--n must be positive, got {args.n}")
    out = check_out_dir("--out", args.out)
    devices = _sweep_devices(args.devices)
    w, h = args.size
    # a chunk of frames in flight, plus every frame's colour + depth for the contact sheet
    need = float(w) * h * (min(args.chunk, args.n) * PIXEL_BYTES + args.n * 8)
    check_memory("--size", f"{w}x{h} (with --n {args.n}, --chunk {args.chunk})", need)
    if _is_skinned_glb(args.mesh):  # a glTF character at its bind pose, with its props
        mp, _ = _skinned_scene(args)
    else:
        mp = mesh_pass(*mesh_arrays(load_mesh(args.mesh, up=args.up)))
    center, dist = _framing(np.asarray(mp.vertices), args.fov)
    cams = orbit_cameras(
        center, dist, args.n, args.elevation, args.fov, w, h, dist * 1e-3, dist * 10
    )

    def render_one(cam):
        fr = composite([background(cam), render_mesh_pass(cam, mp)])
        return {"color": to_uint8(fr.color), "depth": fr.depth}

    def write_frames(k, start, outputs):
        for i, img in enumerate(outputs["color"]):
            p = out / f"frame_{start + i:05d}.png"
            if not p.exists():
                save_png(p, img)

    t0 = time.perf_counter()
    try:
        summary = run_sweep(
            render_one, cams, out / "chunks", args.chunk, devices=devices, on_chunk=write_frames
        )
    except SweepMismatch as exc:  # the frames beside the chunks are stale too
        raise CliError(
            f"--out {out} holds a different sweep: {exc.parts}. To start over, delete {out} "
            "or choose another --out"
        ) from None
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    allv = load_sweep(out / "chunks")
    save_png(out / "contact_sheet.png", contact_sheet(allv["color"], min(args.n, 6)))
    summary["frames"] = args.n
    print(json.dumps(summary))
    return 0


def register(subparsers) -> None:
    """Adds ``render`` and ``sweep`` to the CLI's subparsers."""
    r = subparsers.add_parser(
        "render",
        help="render a mesh file to PNG (+ depth .npy); a skinned .glb is drawn posed",
    )
    r.add_argument(
        "mesh",
        help="PLY/OBJ/GLB/STL file; a .glb's skinned mesh is posed and drawn orange with the "
        "file's other meshes",
    )
    r.add_argument(
        "--time",
        type=bounded_float(0.0, math.inf),
        default=None,
        help="seconds into a skinned .glb's animation, within the clip (default: bind pose)",
    )
    add_up_argument(r)
    r.add_argument(
        "--camera",
        type=parse_floats(5, "x,y,z,yaw,pitch"),
        default=None,
        help="x,y,z,yaw,pitch (degrees; y up, yaw 0 looks along +z); default frames the mesh",
    )
    r.add_argument(
        "--fov", type=parse_fov, default=45.0, help="vertical field of view, degrees in (0, 180)"
    )
    r.add_argument("--size", type=parse_size, default=(640, 480), help="WxH (default 640x480)")
    r.add_argument("--out", default="frame.png", help="output PNG (default frame.png)")
    r.add_argument(
        "--depth", default=None, help="write camera-space depth (+inf = empty) to this .npy"
    )
    r.add_argument("--cull", action="store_true", help="cull back faces")
    r.set_defaults(func=run_render)

    s = subparsers.add_parser("sweep", help="orbit N cameras around a mesh (resumable)")
    s.add_argument(
        "mesh", help="PLY/OBJ/GLB/STL file; a .glb's skinned mesh is drawn at its bind pose"
    )
    add_up_argument(s)
    s.add_argument("--n", type=int, default=12, help="number of cameras")
    s.add_argument("--out", default="sweep", help="output directory (frames, chunks, sheet)")
    s.add_argument("--size", type=parse_size, default=(160, 120), help="WxH (default 160x120)")
    s.add_argument(
        "--fov", type=parse_fov, default=45.0, help="vertical field of view, degrees in (0, 180)"
    )
    s.add_argument(
        "--elevation",
        type=bounded_float(-90.0, 90.0, open_interval=True),
        default=20.0,
        help="degrees above the horizon, in (-90, 90)",
    )
    s.add_argument(
        "--chunk",
        type=positive_int,
        default=4,
        help="cameras per chunk (rounded up to a multiple of the devices)",
    )
    s.add_argument(
        "--devices",
        type=positive_int,
        default=None,
        help="devices to shard each chunk over, at most one per core (default: all; on the "
        "CPU one per core, set through XLA_FLAGS=--xla_force_host_platform_device_count "
        "unless XLA_FLAGS already sets it)",
    )
    s.set_defaults(func=run_sweep)
