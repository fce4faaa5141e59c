"""``jaxgfx voxelize`` and ``jaxgfx render-voxels`` (thesis chapter 4).

Conventions: scene coordinates are voxel units, y up, the subject's front towards
+z (where the default ``render-voxels`` camera stands).  A voxelized mesh of
resolution R occupies [0, R) on its longest axis with its lowest voxel at
y = 0.  Cameras take yaw in degrees about +y (0 looks along +z) and pitch in
degrees (positive looks up).  Depth files hold the distance along the view
axis in voxel units, +inf where nothing was hit.
"""

from __future__ import annotations

import functools
import json
import math
import sys
import time
from pathlib import Path

from jaxgfx.cli.args import (
    CliError,
    bounded_float,
    check_image,
    check_in_file,
    check_memory,
    check_out_file,
    input_errors,
    memory_limit,
    nonnegative_int,
    parse_aa,
    parse_floats,
    parse_fov,
    parse_size,
    positive_int,
    writing,
)
from jaxgfx.cli.framing import (
    FRONT_AXES,
    VOXEL_VIEW,
    axis_vector,
    camera_text,
    framed_camera,
    mesh_front,
    pick_front,
    voxel_side_areas,
    warn_if_unseen,
)

__all__ = ["register", "run_voxelize", "run_render_voxels", "load_input", "face_front"]

UP_AXES = ("x", "y", "z", "-x", "-y", "-z")
"""``voxelize --up`` values: a mesh's up axis (x, y, z) or a volume's (any sign)."""
VOLUME_FRONT = "-y"
"""A volume's front by default, when it is horizontal after ``--up``: the patient
coordinates of DICOM and NRRD (LPS: x to the patient's left, y to the back, z up) put the
face towards -y.  Otherwise (and for meshes) the rule of :mod:`jaxgfx.cli.framing`."""
MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off")


def _formats() -> str:
    """Every input ``voxelize`` reads, in words (for an unsupported suffix)."""
    from jaxgfx._src.voxel.formats import SIMPLEITK_SUFFIXES, VOLUME_SUFFIXES

    return (
        f"meshes ({', '.join(MESH_SUFFIXES)}), volumes ({', '.join(VOLUME_SUFFIXES)}; "
        f"{', '.join(SIMPLEITK_SUFFIXES)} with jaxgfx[volumes]), Voxlap worlds and sprites "
        "(.vxl, .kv6), or the word 'tree'"
    )


def face_front(coords, shape, front_world):
    """Turns voxels about +y so that the world direction ``front_world`` points to +z.

    Args:
        coords: (N, 3) integer voxel coordinates in a grid of ``shape``.
        shape: (X, Y, Z).
        front_world: (3,) axis-aligned direction (+-x or +-z) of the subject's front.

    Returns:
        ``(coords, shape)`` after the quarter or half turn (a rotation, not a mirror).
    """
    import numpy as np

    c = np.asarray(coords, np.int64)
    X, Y, Z = shape
    fx, _, fz = (int(round(v)) for v in front_world)
    if fz == 1:
        return c, (X, Y, Z)
    if fz == -1:  # half turn
        return np.stack([X - 1 - c[:, 0], c[:, 1], Z - 1 - c[:, 2]], 1), (X, Y, Z)
    if fx == 1:  # x -> z, z -> -x
        return np.stack([Z - 1 - c[:, 2], c[:, 1], c[:, 0]], 1), (Z, Y, X)
    # -x -> z, z -> x
    return np.stack([c[:, 2], c[:, 1], X - 1 - c[:, 0]], 1), (Z, Y, X)


def _volume_front_in_world(front: str, up: str):
    """Where a volume's ``front`` axis points after its ``up`` was turned to +y."""
    import numpy as np

    from jaxgfx._src.voxel.volume import turn_up

    probe = np.zeros((3, 3, 3))
    probe[tuple(1 + axis_vector(front).astype(int))] = 1.0
    return np.argwhere(turn_up(probe, up))[0] - 1.0


_CONVENTIONS = (
    "Scene coordinates are voxel units, y up, the subject's front towards +z; a voxelized "
    "mesh of resolution R occupies [0, R) on its longest axis with its lowest voxel at y = 0."
)


VOXEL_BYTES = 8
"""Rough upper bound of the bytes per cell of the ``R^3`` grid that voxelizing works on."""
RAY_BYTES = 256
"""Rough upper bound of the bytes one ray (one pixel of the supersampled frame) costs in
the RLE ray caster (planes, texels, re-walk) and the anti-aliasing pass."""


def check_levels(levels: int, grid: int, what: str) -> None:
    """Refuses mip levels whose coarsest voxel (``2^(levels-1)``) is wider than the grid."""
    if 1 << (levels - 1) > grid:
        top = grid.bit_length()  # largest l with 2^(l-1) <= grid
        raise CliError(
            f"--levels {levels}: the coarsest level would be 2^{levels - 1} voxels wide, more "
            f"than the {what} of {grid}; use --levels <= {top}"
        )


def load_input(
    path: str,
    resolution: int | None,
    iso: float | None,
    seed: int = 0,
    up: str | None = None,
    report: dict | None = None,
    front: str | None = None,
):
    """Reads any supported input as surface :class:`~jaxgfx.raycast.Voxels`.

    ``tree`` (literally) makes a procedural tree from ``seed``.  Volumes keep their
    sample spacing: they are resampled to cubic voxels whose edge is the finest
    spacing, or the longest physical axis split into ``resolution`` voxels; the
    iso value defaults to Otsu's threshold.  Meshes without vertex colours get one
    clay colour.  ``up`` is the file's up axis (meshes: x, y or z, default y;
    volumes: also -x, -y, -z, default z, the slice axis of a scan).  ``front`` is the
    file's axis out of the subject's front; by default a volume's is :data:`VOLUME_FRONT`
    when that is horizontal after ``up``, else (and for meshes) the side the rule of
    :mod:`jaxgfx.cli.framing` picks.  The result is turned about y so that its front
    faces +z, where ``render-voxels`` looks from by default.  For a volume, ``report`` (a dict)
    receives the ``iso`` value used and the file's ``spacing``.

    Raises:
        CliError: the input is missing, a directory, of an unknown format, or cannot be
            read; or an option does not apply to it.
    """
    import jax
    import numpy as np

    from jaxgfx import raycast as V

    p = Path(path)
    ext = p.suffix.lower()
    is_volume = bool(V.volume_suffix(p))
    fixed = ext in (".vxl", ".kv6") or path == "tree"
    if up is not None and fixed:
        raise CliError(f"--up applies to meshes and volumes, not to {path}")
    if front is not None and fixed:
        raise CliError(f"--front applies to meshes and volumes, not to {path}")
    if up is not None and up.startswith("-") and not is_volume:
        raise CliError(f"--up {up}: meshes take x, y or z")
    if ext in (".vxl", ".kv6") and resolution is not None:
        raise CliError(f"--resolution applies to meshes, trees and volumes, not to {ext} files")
    if path != "tree":
        check_in_file("input", path, f"one of {_formats()}")
        if not (fixed or is_volume or ext in MESH_SUFFIXES):
            got = repr(ext) if ext else "no suffix"
            raise CliError(f"input {path!r} has {got}; voxelize reads {_formats()}")
    if resolution is None and not (is_volume or ext in (".vxl", ".kv6")):
        raise CliError("--resolution is required for meshes and trees")
    up_axis = up or ("z" if is_volume else "y")
    facing = None  # decided by the rule once the voxels or vertices are known
    if is_volume:
        facing = _volume_front_in_world(front or VOLUME_FRONT, up_axis)
        if abs(facing[1]) > 0.5:
            if front is not None:
                raise CliError(
                    f"--front {front} is the --up axis ({up_axis}); name a horizontal axis"
                )
            facing = None  # --up made the face's axis vertical: the rule decides
    elif front is not None and not fixed:
        mesh_front(np.zeros((0, 3)), np.zeros((0, 3), int), front=front, up=up_axis)  # fail early
    if ext in (".vxl", ".kv6"):
        with input_errors():
            return V.load_vxl(str(p)) if ext == ".vxl" else V.load_kv6(str(p))
    if is_volume:
        with input_errors():
            vol, spacing = V.load_volume(str(p))
        shape = V.isotropic_shape(vol.shape, spacing, resolution)
        # Resampling holds the float32 volume and its colours: about 8 bytes a voxel.
        need = math.prod(shape) * VOXEL_BYTES
        if resolution is None and need > memory_limit():
            raise CliError(
                f"input {path}: its spacing {tuple(float(s) for s in spacing)} makes "
                f"{'x'.join(map(str, shape))} cubic voxels (about {need / 2**30:.1f} GiB, more "
                "than half the physical memory); pass --resolution N for fewer"
            )
        check_memory("--resolution", str(resolution), need)
        if iso is not None:
            lo, hi = float(vol.min()), float(vol.max())
            if not lo < iso <= hi:
                raise CliError(f"--iso {iso} is outside the volume's range ({lo}, {hi}]")
        if iso is None:
            iso = V.otsu_threshold(vol)
        if report is not None:
            report.update(iso=round(float(iso), 4), spacing=[float(v) for v in spacing])
        # By default volume z (the slice axis of a scan) becomes world y.
        vox = V.volume_to_voxels(vol, iso, up_axis=up_axis, spacing=spacing, resolution=resolution)
        if facing is None:
            facing = pick_front(voxel_side_areas(vox.coords))
        coords, shape = face_front(vox.coords, vox.shape, facing)
        return V.make_voxels(coords, vox.colors, shape)
    assert resolution is not None  # required for meshes and trees (checked above)
    if path == "tree":
        return V.procedural_tree(resolution, key=jax.random.key(seed))
    from jaxgfx.io import load_mesh

    with input_errors():
        mesh = load_mesh(p, up=up_axis)
    colors = None
    visual = getattr(mesh, "visual", None)
    if visual is not None and getattr(visual, "kind", None) == "vertex":
        colors = np.asarray(visual.vertex_colors)[:, :3]
    vertices = np.asarray(mesh.vertices)
    facing = mesh_front(vertices, np.asarray(mesh.faces), front=front, up=up_axis, path=str(p))
    if facing[2] < 0.5:  # turn the front to +z: a quarter or half turn about y
        a = math.atan2(facing[0], facing[2])
        c, sn = round(math.cos(a)), round(math.sin(a))
        vertices = vertices @ np.array([[c, 0, -sn], [0, 1, 0], [sn, 0, c]], float).T
    return V.voxelize_mesh(vertices, mesh.faces, resolution, vertex_colors=colors)


def run_voxelize(args) -> int:
    """Voxelizes an input and prints one JSON line with the memory accounting."""
    out = check_out_file("--out", args.out, (".npz",))
    if args.resolution is not None:
        r = args.resolution
        check_memory("--resolution", str(r), float(r) ** 3 * VOXEL_BYTES)
        check_levels(args.levels, r, "--resolution")

    from jaxgfx import raycast as V

    t0 = time.perf_counter()
    volume: dict = {}
    vox = load_input(
        args.input, args.resolution, args.iso, args.seed, args.up, volume, front=args.front
    )
    check_levels(args.levels, max(vox.shape), "largest grid axis")
    rle = V.encode_rle(vox, levels=args.levels)
    st = V.rle_stats(rle)
    with writing("--out", out):
        V.save_scene(str(out), vox)
    line = dict(
        input=str(args.input),
        shape=list(vox.shape),
        voxels=st["voxels"],
        surface_voxels=st["voxels"],
        rle_elements=st["rle_elements_level0"],
        rle_elements_all_levels=st["rle_elements"],
        levels=args.levels,
        bytes=st["bytes_with_color"],
        position_bytes=st["position_bytes"],
        bits_per_voxel=round(st["bits_per_voxel"], 3),
        seconds=round(time.perf_counter() - t0, 3),
        out=str(args.out),
        **volume,
    )
    print(json.dumps(line))
    return 0


def frame_voxels(vox, fov: float, width: int, height: int):
    """The default camera of ``render-voxels``: every voxel of the scene in view.

    Seen from the scene's front (+z), 20 degrees from above (yaw 180, pitch -20), at the
    nearest distance where every voxel cube lies inside the view with the CLI's margin
    (:func:`jaxgfx.camera.frame_points` with ``half_size`` 0.5).

    Returns:
        The :class:`~jaxgfx.camera.Camera` (near 0.05 voxels, far as the caller sets).
    """
    import numpy as np

    c = np.asarray(vox.coords, np.float64) + 0.5
    if len(c) == 0:  # an empty scene: frame its grid
        c = np.array(list(np.ndindex(2, 2, 2)), np.float64) * np.asarray(vox.shape, float)
    return framed_camera(c, VOXEL_VIEW, fov, (width, height), half_size=0.5)


def warn_lost_elements(stats: dict, cam) -> None:
    """Tells on stderr that a frame lost drawn elements, and the option that keeps them.

    The wide traversal (a map beyond the scatter's limits) keeps ``buffer_size`` drawn
    elements per plane (a static size), drops the farthest past a plane's buffer and
    counts them (``stats["buffer_overflow"]``); the frame then misses part of the scene.

    Args:
        stats: the frame's stats as ints (``buffer_overflow``, ``elements_rendered``).
        cam: its camera (the ``--aa`` grid).
    """
    lost, drawn = stats["buffer_overflow"], stats["elements_rendered"]
    if lost <= 0:
        return
    # Each drawn element covers at least one new row of its plane: one per row fits.
    print(
        f"warning: {lost} of the {drawn} drawn elements did not fit the frame's lists, so "
        f"part of the scene is missing from the image; rerun with "
        f"--buffer-size {max(cam.width, cam.height)}",
        file=sys.stderr,
    )


SCENE_KIND = "a scene .npz written by 'jaxgfx voxelize'"


def _check_scene_path(scene: str) -> None:
    """Names what a file is when it is not a scene: a mesh, a volume, a Voxlap file."""
    from jaxgfx import raycast as V

    ext = Path(scene).suffix.lower()
    if ext == ".npz" or Path(scene).is_dir():
        check_in_file("scene", scene, SCENE_KIND)
        return
    kind = (
        "a mesh"
        if ext in MESH_SUFFIXES
        else "a Voxlap file"
        if ext in (".vxl", ".kv6")
        else "a volume"
        if V.volume_suffix(scene)
        else None
    )
    if kind is not None:
        res = "" if kind == "a Voxlap file" or kind == "a volume" else " --resolution 128"
        raise CliError(
            f"scene {scene!r} is {kind}, not {SCENE_KIND}; voxelize it first: jaxgfx "
            f"voxelize {scene}{res} --out scene.npz"
        )
    got = repr(ext) if ext else "no suffix"
    raise CliError(f"scene {scene!r} has {got}; render-voxels reads {SCENE_KIND}")


def _finish(cam, color, depth, key, lit: bool, aa: tuple[int, int]):
    """Lights the ray-cast frame (unless ``lit`` is False), puts it on the sky and averages
    the anti-aliasing grid back: ``(color, depth)`` at the output size."""
    import jax.numpy as jnp

    from jaxgfx.compose import background
    from jaxgfx.post import antialias, shade_voxels

    if lit:
        # Lit on the supersampled frame, before it is averaged back (4.5.6).
        color = shade_voxels(cam, color, depth, key=key)
    sky = background(cam).color  # the sky of jaxgfx render
    color = jnp.where(jnp.isfinite(depth)[..., None], color, sky)
    return antialias(color, depth, aa)


@functools.cache
def _finish_jit():
    import jax

    return jax.jit(_finish, static_argnums=(4, 5))


def run_render_voxels(args) -> int:
    """Renders a saved voxel scene to a PNG (and optionally a depth .npy)."""
    out_png = check_out_file("--out", args.out, (".png",))
    depth_npy = check_out_file("--depth", args.depth, (".npy",)) if args.depth else None
    check_image(args.size, RAY_BYTES * args.aa[0] * args.aa[1])
    _check_scene_path(args.scene)

    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxgfx import raycast as RC
    from jaxgfx.camera import camera_from_degrees, supersampled
    from jaxgfx.io import save_npy, save_png

    with input_errors():
        vox = RC.load_scene(args.scene)
    check_levels(args.levels, max(vox.shape), "scene's largest axis")
    w, h = args.size
    if args.camera is not None:
        x, y, z, yaw, pitch = args.camera
        view = camera_from_degrees([x, y, z], yaw, pitch, 0.0, args.fov, w, h, far=args.far)
    else:
        view = frame_voxels(vox, args.fov, w, h)
        view = camera_from_degrees(
            np.asarray(view.position),
            math.degrees(float(view.yaw)),
            math.degrees(float(view.pitch)),
            0.0,
            args.fov,
            w,
            h,
            far=args.far,
        )
    # Anti-aliasing (4.5.6.2): the same view on a finer grid, averaged back.
    cam = supersampled(view, args.aa)
    rle = RC.encode_rle(vox, levels=args.levels)
    with input_errors("--camera"):
        RC.check_camera_outside(rle, cam)
    t0 = time.perf_counter()
    if args.reference:
        occ, col = RC.voxels_to_dense(vox)
        fn = jax.jit(RC.reference_render)
        out, _ = fn(jnp.asarray(occ), jnp.asarray(col), cam)
        stats = {}
    else:
        fn = jax.jit(RC.render_rle)
        settings = RC.RenderSettings(
            refine_steps=0 if args.thesis else args.refine,
            oversample=1.0 if args.thesis else args.oversample,
            neighbors=0 if args.thesis else 1,
            # The thesis's fixed per-pixel plane spacing (no distance-driven planes).
            planes_per_voxel=0.0 if args.thesis else RC.RenderSettings().planes_per_voxel,
            buffer_size=args.buffer_size,
            traversal=args.traversal,
        )
        out = fn(
            RC.as_jax(rle),
            cam,
            settings=settings,
            lod_distance=args.lod if args.lod > 0 else jnp.inf,
        )
        stats = {k: int(v) for k, v in out.stats.items()}
        warn_lost_elements(stats, cam)
    color, depth = _finish_jit()(
        cam, out.color, out.depth, jax.random.key(0), not args.unlit, tuple(args.aa)
    )
    jax.block_until_ready(depth)
    seconds = time.perf_counter() - t0
    with writing("--out", out_png):
        save_png(out_png, color)
    if depth_npy is not None:
        with writing("--depth", depth_npy):
            save_npy(depth_npy, depth)
    hits = int(jnp.sum(jnp.isfinite(depth)))
    warn_if_unseen(
        "render-voxels",
        view,
        np.asarray(vox.coords, np.float64) + 0.5,
        hits,
        f"scene {args.scene!r}",
        fov=args.fov,
    )
    print(
        json.dumps(
            dict(
                out=str(args.out),
                depth=str(args.depth) if args.depth else None,
                renderer="reference-dda" if args.reference else "rle-planes",
                camera=camera_text(view),
                lit=not args.unlit,
                seconds_incl_compile=round(seconds, 3),
                aa="{}x{}".format(*args.aa),
                hit_pixels=hits,
                **stats,
            )
        )
    )
    return 0


def register(subparsers) -> None:
    """Adds ``voxelize`` and ``render-voxels`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "voxelize",
        help="mesh / volume / .vxl / .kv6 / 'tree' -> surface voxels (.npz) + RLE stats",
        description="Voxelize an input into surface voxels and report the RLE memory use "
        "(thesis 4.3, 4.4.6). " + _CONVENTIONS + " Meshes keep their vertex colours, else "
        "one clay colour. Volumes keep their sample spacing (resampled to cubic voxels, "
        "trilinear), their slice axis (z) becomes y and their front (-y, the face in DICOM "
        "and NRRD patient coordinates) faces +z; a mesh's front (the side the most surface "
        "faces, unless --front or glTF says) faces +z too; see --up and --front.",
    )
    p.add_argument("input", help="mesh (.ply/.obj/...), volume (.mhd, .nhdr/.nrrd, .vtk; "
                   ".nii, .mha, ... with jaxgfx[volumes]), .vxl, .kv6, "
                   "or the word 'tree'")  # fmt: skip
    p.add_argument("--resolution", type=positive_int, default=None,
                   help="grid size of the longest axis (meshes and trees: required; volumes: "
                   "default the finest sample spacing is one voxel)")  # fmt: skip
    p.add_argument("--iso", type=float, default=None,
                   help="iso threshold for volumes (default: Otsu's threshold of the values, "
                   "the boundary between air and the object)")  # fmt: skip
    p.add_argument("--up", choices=UP_AXES, default=None,
                   help="the file's up axis, turned to y: meshes x|y|z (default y), volumes "
                   "also -x|-y|-z (default z, the slice axis; write --up=-z)")  # fmt: skip
    p.add_argument("--front", choices=FRONT_AXES, default=None,
                   help="the file's axis out of the subject's front, turned to +z where "
                   "render-voxels looks from (write --front=-y). Default: volumes -y (the "
                   "face in the patient coordinates of DICOM and NRRD) unless --up makes "
                   "it vertical, glTF meshes z; else, of the four sides +z, +x, -z, -x "
                   "(after --up), the one the most surface faces (area-weighted normals, "
                   "voxel faces; for a closed surface its broad side), ties within 2%% "
                   "going to that order")  # fmt: skip
    p.add_argument("--levels", type=positive_int, default=1, help="mip levels to encode")
    p.add_argument("--seed", type=int, default=0, help="seed for 'tree'")
    p.add_argument("--out", required=True, help="output scene (.npz)")
    p.set_defaults(func=run_voxelize)

    r = subparsers.add_parser(
        "render-voxels",
        help="render a voxel scene with the per-plane RLE ray caster",
        description="Render a scene written by 'jaxgfx voxelize' (thesis 4.5). "
        + _CONVENTIONS
        + " --camera is x,y,z,yaw,pitch: yaw in degrees about +y (0 looks along +z), "
        "pitch in degrees (positive looks up); without it the camera frames the scene. "
        "The frame is lit by screen-space normals and ambient occlusion (thesis 4.5.6) "
        "unless --unlit. The --depth file holds the distance along "
        "the view axis in voxel units, +inf where nothing was hit.",
    )
    r.add_argument("scene", help="scene .npz from 'jaxgfx voxelize'")
    r.add_argument(
        "--camera",
        type=parse_floats(5, "x,y,z,yaw,pitch"),
        default=None,
        help="x,y,z,yaw,pitch (default: frames the scene from its front, 20 degrees above)",
    )
    r.add_argument("--unlit", action="store_true",
                   help="write the voxels' colours unshaded (default: lit by screen-space "
                   "normals and ambient occlusion)")  # fmt: skip
    r.add_argument(
        "--fov", type=parse_fov, default=60.0, help="vertical field of view, degrees in (0, 180)"
    )
    r.add_argument("--size", type=parse_size, default=(640, 480), help="WxH")
    r.add_argument(
        "--far",
        type=bounded_float(0.0, math.inf, open_interval=True),
        default=1e5,
        help="maximal view distance (voxels)",
    )
    r.add_argument("--levels", type=positive_int, default=1, help="mip levels (LOD)")
    r.add_argument("--lod", type=bounded_float(0.0, math.inf), default=0.0,
                   help="distance where mip level 1 starts, level l at lod * 2^(l-1) "
                   "(0: level 0 only; 2 x the focal length in pixels keeps mip cells "
                   "about a pixel wide: jaxgfx.raycast.lod_distance_for)")  # fmt: skip
    r.add_argument("--refine", type=nonnegative_int, default=None,
                   help="exact re-walk steps for pixels whose ray met no sampled voxel "
                   "(0: off; default: RenderSettings.refine_steps' choice)")  # fmt: skip
    r.add_argument("--oversample", type=bounded_float(0.0, math.inf, open_interval=True),
                   default=2.0,
                   help="planes per border pixel (1 = thesis Eq. 4.4; 2 = default)")  # fmt: skip
    r.add_argument("--traversal", choices=("auto", "scatter", "wide"),
                   default="auto",
                   help="how the ray buffer is drawn (RenderSettings.traversal; auto: "
                   "scatter, wide for a map beyond the scatter's limits)")  # fmt: skip
    r.add_argument("--buffer-size", type=positive_int, default=None,
                   help="wide traversal: drawn elements kept per plane (default "
                   "max(64, max(W, H) / 2) at the --aa grid; max(W, H) always suffices); a "
                   "frame that draws more loses its farthest elements and says so on "
                   "stderr")  # fmt: skip
    r.add_argument("--thesis", action="store_true",
                   help="the thesis method alone: 1 plane per border pixel at any "
                   "distance, nearest texel, no re-walk")  # fmt: skip
    r.add_argument("--aa", type=parse_aa, default=(1, 1),
                   help="anti-aliasing 1x1 (off), 2x1 (thesis: pixels half as wide) or 2x2; "
                   "the frame is rendered at the finer grid and averaged back to --size, "
                   "the depth is the nearest sample")  # fmt: skip
    r.add_argument("--out", required=True, help="output PNG (.png)")
    r.add_argument("--depth", default=None, help="optional depth (.npy)")
    r.add_argument("--reference", action="store_true",
                   help="use the per-pixel 3-D DDA reference renderer instead")  # fmt: skip
    r.set_defaults(func=run_render_voxels)
