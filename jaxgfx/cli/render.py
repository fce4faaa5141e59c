"""``jaxgfx render`` and ``jaxgfx sweep``: a mesh drawn by the rasterizer, one view or an orbit.

A ``.glb`` with a skinned mesh (a glTF character such as the sample Fox) is drawn as glTF
means it: the skinned mesh posed by its joints (the bind pose, or ``--time`` seconds into its
first animation clip; linear blend skinning), plus the file's other meshes at their node
transforms.  trimesh, which reads every other file, ignores skins and draws the character at
its mesh node's transform (for the Fox: a dot beside its stand).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from jaxgfx.cli.args import (
    PIXEL_BYTES,
    CliError,
    Interrupted,
    add_up_argument,
    bounded_float,
    check_image,
    check_in_file,
    check_memory,
    check_out_dir,
    check_out_file,
    input_errors,
    parse_floats,
    parse_fov,
    parse_size,
    positive_int,
    writing,
)
from jaxgfx.cli.framing import (
    CHARACTER_VIEW,
    FRONT_AXES,
    MESH_VIEW,
    camera_text,
    framed_camera,
    mesh_front,
    orbit_distance,
    turn_view,
    warn_if_unseen,
)

CHARACTER_COLOR = (0.85, 0.5, 0.25)
"""The skinned mesh of a ``.glb`` without a base colour texture is drawn in this colour."""

MESH_KIND = "a mesh file (.ply, .obj, .glb, .gltf, .stl, .off)"

SHEET_TILES = 48
"""The contact sheet shows at most this many frames, evenly spaced over the sweep."""
SHEET_SIDE = 2048
"""The contact sheet's longer side is at most this many pixels (tiles are shrunk)."""

__all__ = ["register", "run_render", "run_sweep", "contact_sheet", "sheet_layout"]


def _bounds(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius (half the diagonal) of the bounding box."""
    lo, hi = vertices.min(0), vertices.max(0)
    return 0.5 * (lo + hi), float(np.linalg.norm(hi - lo)) * 0.5 + 1e-6


def _camera_for(vertices: np.ndarray, args: argparse.Namespace, view=MESH_VIEW, faces=None):
    """``--camera`` if given, else the view along ``view`` (given for a subject facing +z,
    turned to the mesh's front: ``--front`` or the rule of :mod:`jaxgfx.cli.framing`) that
    frames every vertex."""
    from jaxgfx.camera import camera_from_degrees

    w, h = args.size
    if args.camera is not None:
        _, radius = _bounds(vertices)
        x, y, z, yaw, pitch = args.camera
        return camera_from_degrees(
            [x, y, z], yaw, pitch, 0.0, args.fov, w, h, radius * 1e-3, radius * 1e3
        )
    front = mesh_front(
        vertices,
        np.zeros((0, 3), np.int64) if faces is None else faces,
        front=getattr(args, "front", None),
        up=args.up,
        path=args.mesh,
    )
    return framed_camera(vertices, turn_view(view, front), args.fov, args.size)


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

    with input_errors():
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
    # A textured character is drawn in its texture's colours, otherwise in CHARACTER_COLOR.
    base = CHARACTER_COLOR if gskin.texture is None else (1.0, 1.0, 1.0)
    color = np.tile(np.asarray(base, np.float32), (len(gskin.vertices), 1))
    textures = [gskin.texture] if gskin.texture is not None else []
    passes = [
        mesh_pass(
            np.asarray(pos) @ rot.T, gskin.faces, color, np.asarray(nrm) @ rot.T,
            uvs=gskin.uvs, texture=gskin.texture,
        )
    ]  # fmt: skip
    with input_errors():
        props = skin.load_gltf_meshes(args.mesh)
    dropped = 0
    for m in props:
        # One texture a pass: a prop's own texture is drawn when the character has none.
        own = m.texture is not None and not textures
        dropped += int(m.texture is not None and not own)
        if m.texture is not None and own:
            textures.append(m.texture)
        passes.append(
            mesh_pass(m.vertices @ rot.T, m.faces, m.colors,
                      uvs=m.uvs if own else None, texture=m.texture if own else None)
        )  # fmt: skip
    info = dict(skinned_vertices=len(gskin.vertices), time=t, props=len(passes) - 1)
    info.update(textured=bool(textures), textures_not_drawn=dropped)
    return merge_mesh_passes(passes), info


def _load_mesh_pass(args: argparse.Namespace, skinned: bool | None = None):
    """The mesh file as one :class:`MeshPass`, whether it is skinned (+ summary info)."""
    from jaxgfx.io import load_mesh, mesh_arrays, mesh_texture
    from jaxgfx.scene import mesh_pass

    check_in_file("mesh", args.mesh, MESH_KIND)
    if skinned is None:
        skinned = _is_skinned_glb(args.mesh)
    if skinned:  # a glTF character, posed, with its props
        mp, info = _skinned_scene(args)
        return mp, info, True
    with input_errors():
        mesh = load_mesh(args.mesh, up=args.up)
        v, f, colors = mesh_arrays(mesh)
        uvs, image = mesh_texture(mesh)
        if image is not None:  # the texture gives the colours
            colors = np.ones_like(colors)
        mp = mesh_pass(v, f, colors, uvs=uvs, texture=image)
    return mp, {"textured": image is not None}, False


def _frame(cam, mp, cull: bool):
    from jaxgfx.compose import background, composite
    from jaxgfx.scene import render_mesh_pass

    return composite([background(cam), render_mesh_pass(cam, mp, cull_backfaces=cull)])


@functools.cache
def _frame_jit():
    import jax

    return jax.jit(_frame, static_argnums=2)


def run_render(args: argparse.Namespace) -> int:
    """Renders one view of a mesh; writes the PNG (and depth) and prints one JSON line."""
    out = check_out_file("--out", args.out, (".png",))
    depth = check_out_file("--depth", args.depth, (".npy",)) if args.depth else None
    check_image(args.size, PIXEL_BYTES)
    check_in_file("mesh", args.mesh, MESH_KIND)
    skinned = _is_skinned_glb(args.mesh)
    if args.time is not None and not skinned:
        raise CliError(f"--time applies to a .glb with a skinned mesh, not {args.mesh}")

    import jax

    from jaxgfx.io import save_npy, save_png

    mp, info, skinned = _load_mesh_pass(args, skinned)
    v, f = np.asarray(mp.vertices), np.asarray(mp.faces)
    cam = _camera_for(v, args, CHARACTER_VIEW if skinned else MESH_VIEW, f)
    t0 = time.perf_counter()
    frame = jax.block_until_ready(_frame_jit()(cam, mp, bool(args.cull)))
    dt = time.perf_counter() - t0
    d = np.asarray(frame.depth)
    with writing("--out", out):
        save_png(out, frame.color)
    if depth is not None:
        with writing("--depth", depth):
            save_npy(depth, d)
    hits = int(np.isfinite(d).sum())
    warn_if_unseen("render", cam, v, hits, f"mesh {args.mesh!r}", faces=f, fov=args.fov)
    summary = dict(
        out=str(args.out),
        triangles=len(f),
        camera=camera_text(cam),
        seconds=round(dt, 3),
        coverage=hits / d.size,
    )
    print(json.dumps({**summary, **info}))
    return 0


def sheet_layout(n: int, size: tuple[int, int]) -> tuple[list[int], int, int]:
    """Which frames the contact sheet shows, its columns and the tiles' shrink factor.

    At most :data:`SHEET_TILES` frames, evenly spaced from the first to the last, in up to
    6 columns; tiles are shrunk by a whole factor until the sheet's longer side is at most
    :data:`SHEET_SIDE` pixels.

    Args:
        n: frames in the sweep.
        size: (W, H) of a frame.

    Returns:
        ``(frame indices, columns, shrink factor)``.
    """
    picks = sorted({round(k * (n - 1) / (SHEET_TILES - 1)) for k in range(SHEET_TILES)})
    picks = list(range(n)) if n <= SHEET_TILES else picks
    cols = min(len(picks), 6)
    rows = -(-len(picks) // cols)
    w, h = size
    shrink = max(1, -(-max(cols * w, rows * h) // SHEET_SIDE))
    return picks, cols, shrink


def contact_sheet(images: np.ndarray, cols: int, shrink: int = 1) -> np.ndarray:
    """Tiles (N, H, W, 3) uint8 images into one grid image, each shrunk ``shrink`` times
    (box average; a partial last row or column of pixels is dropped)."""
    n, h, w, ch = images.shape
    if shrink > 1:
        hs, ws = h // shrink, w // shrink
        cut = images[:, : hs * shrink, : ws * shrink].astype(np.float32)
        images = cut.reshape(n, hs, shrink, ws, shrink, ch).mean(axis=(2, 4))
        images = (images + 0.5).astype(np.uint8)
        h, w = hs, ws
    rows = -(-n // cols)
    sheet = np.zeros((rows * h, cols * w, ch), np.uint8)
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


FRAME_PATTERN = "../frame_{i:05d}.png"
"""Where ``jaxgfx sweep`` stores each frame's colour, relative to ``OUT/chunks``."""


def _frames_kept(out: Path, n: int) -> int:
    """Frames of a sweep whose chunks are complete in ``out`` (what a resume skips)."""
    chunks = out / "chunks"
    try:
        manifest = json.loads((chunks / "manifest.json").read_text())
    except (OSError, ValueError):
        return 0
    size = int(manifest.get("chunk_size", 1))
    done = sum(
        min(size, n - k * size)
        for k in range(int(manifest.get("n_chunks", 0)))
        if (chunks / f"chunk_{k:05d}.npz").is_file()
    )
    return min(done, n)


def run_sweep(args: argparse.Namespace) -> int:
    """Orbits ``--n`` cameras around a mesh, chunk by chunk (resumable); writes frames + sheet.

    Each frame's colour is stored as ``OUT/frame_XXXXX.png`` and its depth, compressed, in
    ``OUT/chunks``; Ctrl-C keeps every finished chunk and says how to resume.
    """
    from jaxgfx.camera import orbit_cameras
    from jaxgfx.compose import to_uint8
    from jaxgfx.io import save_png
    from jaxgfx.sweep import SweepMismatch, image_path, run_sweep

    if args.n <= 0:
        raise CliError(f"--n must be positive, got {args.n}")
    out = check_out_dir("--out", args.out)
    check_in_file("mesh", args.mesh, MESH_KIND)
    devices = _sweep_devices(args.devices)
    w, h = args.size
    # a chunk of frames in flight, plus the contact sheet's frames
    need = float(w) * h * (min(args.chunk, args.n) * PIXEL_BYTES + SHEET_TILES * 3)
    check_memory("--size", f"{w}x{h} (with --chunk {args.chunk})", need)
    mp, _, _ = _load_mesh_pass(args)  # a skinned glTF character at its bind pose
    v = np.asarray(mp.vertices, np.float64)
    center, _ = _bounds(v)
    # the sphere about the box's centre through the farthest vertex: seen from any side of
    # the orbit, every vertex stays inside it
    radius = float(np.linalg.norm(v - center, axis=1).max()) + 1e-6
    dist = orbit_distance(radius, args.fov, args.size)
    cams = orbit_cameras(
        center, dist, args.n, args.elevation, args.fov, w, h, dist * 1e-3, dist * 10
    )

    def render_one(cam):
        fr = _frame(cam, mp, False)
        return {"color": to_uint8(fr.color), "depth": fr.depth}

    t0 = time.perf_counter()
    try:
        with writing("--out", out):
            summary = run_sweep(
                render_one,
                cams,
                out / "chunks",
                args.chunk,
                devices=devices,
                images={"color": FRAME_PATTERN},
            )
    except SweepMismatch as exc:  # the frames beside the chunks are stale too
        raise CliError(
            f"--out {out} holds a different sweep: {exc.parts}. To start over, delete {out} "
            "or choose another --out"
        ) from None
    except KeyboardInterrupt:
        kept = _frames_kept(out, args.n)
        raise Interrupted(
            f"{kept} of {args.n} frames are kept in {out}; run the same command again to "
            "render the rest"
        ) from None
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    import imageio.v3 as iio

    picks, cols, shrink = sheet_layout(args.n, args.size)
    tiles = np.stack([iio.imread(image_path(out / "chunks", FRAME_PATTERN, i)) for i in picks])
    with writing("--out", out / "contact_sheet.png"):
        save_png(out / "contact_sheet.png", contact_sheet(tiles, cols, shrink))
    summary["frames"] = args.n
    summary["bytes"] = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
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
        help="PLY/OBJ/GLB/STL file, drawn with its base colour texture where it has one; a "
        ".glb's skinned mesh is posed (orange without a texture) with the file's other meshes",
    )
    r.add_argument(
        "--time",
        type=bounded_float(0.0, math.inf),
        default=None,
        help="seconds into a skinned .glb's animation, within the clip (default: bind pose)",
    )
    add_up_argument(r)
    r.add_argument(
        "--front",
        choices=FRONT_AXES,
        default=None,
        help="the file's axis out of the subject's front, where the default camera stands "
        "(write --front=-y). Default: +z for glTF; else, of the four sides +z, +x, -z, -x "
        "(after --up), the one the most surface faces (area-weighted normals; for a closed "
        "mesh its broad side), ties within 2%% going to that order",
    )
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
