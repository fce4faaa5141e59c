"""``jaxgfx voxelize`` and ``jaxgfx render-voxels`` (thesis chapter 4).

Conventions: scene coordinates are voxel units, y up.  A voxelized mesh of
resolution R occupies [0, R) on its longest axis with its lowest voxel at
y = 0.  Cameras take yaw in degrees about +y (0 looks along +z) and pitch in
degrees (positive looks up).  Depth files hold the distance along the view
axis in voxel units, +inf where nothing was hit.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

from jaxgfx.cli.args import (
    CliError,
    bounded_float,
    check_image,
    check_memory,
    check_out_file,
    memory_limit,
    nonnegative_int,
    parse_aa,
    parse_floats,
    parse_fov,
    parse_size,
    positive_int,
)

__all__ = ["register", "run_voxelize", "run_render_voxels", "load_input"]

UP_AXES = ("x", "y", "z", "-x", "-y", "-z")
"""``voxelize --up`` values: a mesh's up axis (x, y, z) or a volume's (any sign)."""

_CONVENTIONS = (
    "Scene coordinates are voxel units, y up; a voxelized mesh of resolution R occupies "
    "[0, R) on its longest axis with its lowest voxel at y = 0."
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
):
    """Reads any supported input as surface :class:`~jaxgfx.raycast.Voxels`.

    ``tree`` (literally) makes a procedural tree from ``seed``.  Volumes keep their
    sample spacing: they are resampled to cubic voxels whose edge is the finest
    spacing, or the longest physical axis split into ``resolution`` voxels; the
    iso value defaults to Otsu's threshold.  Meshes without vertex colours get one
    clay colour.  ``up`` is the file's up axis (meshes: x, y or z, default y;
    volumes: also -x, -y, -z, default z, the slice axis of a scan).  For a volume,
    ``report`` (a dict) receives the ``iso`` value used and the file's ``spacing``.
    """
    import jax
    import numpy as np

    from jaxgfx import raycast as V

    p = Path(path)
    ext = p.suffix.lower()
    is_volume = bool(V.volume_suffix(p))
    if up is not None and (ext in (".vxl", ".kv6") or path == "tree"):
        raise CliError(f"--up applies to meshes and volumes, not to {path}")
    if up is not None and up.startswith("-") and not is_volume:
        raise CliError(f"--up {up}: meshes take x, y or z")
    if ext in (".vxl", ".kv6"):
        if resolution is not None:
            raise ValueError(
                f"--resolution applies to meshes, trees and volumes, not to {ext} files"
            )
        return V.load_vxl(str(p)) if ext == ".vxl" else V.load_kv6(str(p))
    if is_volume:
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
        return V.volume_to_voxels(
            vol, iso, up_axis=up or "z", spacing=spacing, resolution=resolution
        )
    if resolution is None:
        raise ValueError("--resolution is required for meshes and trees")
    if path == "tree":
        return V.procedural_tree(resolution, key=jax.random.key(seed))
    from jaxgfx.io import load_mesh

    mesh = load_mesh(p, up=up or "y")
    colors = None
    visual = getattr(mesh, "visual", None)
    if visual is not None and getattr(visual, "kind", None) == "vertex":
        colors = np.asarray(visual.vertex_colors)[:, :3]
    return V.voxelize_mesh(mesh.vertices, mesh.faces, resolution, vertex_colors=colors)


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
    vox = load_input(args.input, args.resolution, args.iso, args.seed, args.up, volume)
    check_levels(args.levels, max(vox.shape), "largest grid axis")
    rle = V.encode_rle(vox, levels=args.levels)
    st = V.rle_stats(rle)
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


def frame_voxels(vox, fov: float, width: int, height: int) -> list[float]:
    """A camera ``[x, y, z, yaw, pitch]`` that frames a voxel set's bounding box.

    Seen from the +z side, 20 degrees from above (yaw 180, pitch -20), at the
    nearest distance where all eight corners of the box lie inside the view with a
    5 % margin (like ``jaxgfx render``'s framing, but fitted to the box's corners
    rather than its bounding sphere, so thin and flat scenes fill the frame).
    """
    import itertools

    import numpy as np

    from jaxgfx.camera import camera_basis, camera_from_degrees

    c = np.asarray(vox.coords, np.float64)
    lo, hi = (c.min(0), c.max(0) + 1.0) if len(c) else (np.zeros(3), np.asarray(vox.shape, float))
    center = 0.5 * (lo + hi)
    yaw, pitch = 180.0, -20.0
    probe = camera_from_degrees(center, yaw, pitch, 0.0, fov, width, height)
    right, up, forward = (np.asarray(v, np.float64) for v in camera_basis(probe))
    tan_y = math.tan(math.radians(fov) / 2)
    tan_x = tan_y * width / height
    corners = np.array(list(itertools.product(*zip(lo, hi)))) - center
    # Camera at center - dist * forward: a corner p is at depth dist + p.f; it is
    # inside the view when |p.r| <= tan_x * depth and |p.u| <= tan_y * depth.
    need = np.maximum(np.abs(corners @ right) / tan_x, np.abs(corners @ up) / tan_y)
    dist = float(np.max(need - corners @ forward)) * 1.05 + 1.0
    eye = center - dist * forward
    return [*(round(float(v), 3) for v in eye), yaw, pitch]


def warn_lost_elements(stats: dict, settings, cam) -> None:
    """Tells on stderr that a frame lost drawn elements, and the option that keeps them.

    The renderer keeps ``buffer_size`` drawn elements per plane and ``pool_size`` per
    frame (static sizes), drops the farthest past either and counts them
    (``stats["buffer_overflow"]``); the frame then misses part of the scene.

    Args:
        stats: the frame's stats as ints (``buffer_overflow``, ``elements_rendered``).
        settings: the :class:`~jaxgfx.raycast.RenderSettings` it was rendered with.
        cam: its camera (the ``--aa`` grid).
    """
    lost, drawn = stats["buffer_overflow"], stats["elements_rendered"]
    if lost <= 0:
        return
    from jaxgfx._src.voxel.render import default_pool_size

    pool = settings.pool_size or default_pool_size(cam.width, cam.height, settings.oversample)
    fixes = []
    if drawn > pool:
        # A quarter more than this frame drew, so a nearby view fits too; whole KiB.
        fixes.append(f"--pool-size {-(-drawn * 5 // 4 // 1024) * 1024}")
    if lost > max(drawn - pool, 0):
        # Each drawn element covers at least one new row of its plane: one per row fits.
        fixes.append(f"--buffer-size {max(cam.width, cam.height)}")
    print(
        f"warning: {lost} of the {drawn} drawn elements did not fit the frame's lists, so "
        f"part of the scene is missing from the image; rerun with {' '.join(fixes)}",
        file=sys.stderr,
    )


def run_render_voxels(args) -> int:
    """Renders a saved voxel scene to a PNG (and optionally a depth .npy)."""
    out_png = check_out_file("--out", args.out, (".png",))
    depth_npy = check_out_file("--depth", args.depth, (".npy",)) if args.depth else None
    check_image(args.size, RAY_BYTES * args.aa[0] * args.aa[1])

    import jax
    import jax.numpy as jnp

    from jaxgfx import raycast as RC
    from jaxgfx.camera import camera_from_degrees, supersampled
    from jaxgfx.io import save_npy, save_png
    from jaxgfx.post import antialias, shade_voxels

    vox = RC.load_scene(args.scene)
    check_levels(args.levels, max(vox.shape), "scene's largest axis")
    w, h = args.size
    camera = args.camera if args.camera is not None else frame_voxels(vox, args.fov, w, h)
    x, y, z, yaw, pitch = camera
    cam = camera_from_degrees([x, y, z], yaw, pitch, 0.0, args.fov, w, h, far=args.far)
    # Anti-aliasing (4.5.6.2): the same view on a finer grid, averaged back.
    cam = supersampled(cam, args.aa)
    rle = RC.encode_rle(vox, levels=args.levels)
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
            pool_size=args.pool_size,
            buffer_size=args.buffer_size,
        )
        out = fn(
            RC.as_jax(rle),
            cam,
            settings=settings,
            lod_distance=args.lod if args.lod > 0 else jnp.inf,
        )
        stats = {k: int(v) for k, v in out.stats.items()}
        warn_lost_elements(stats, settings, cam)
    color = out.color
    if not args.unlit:
        # Lit on the supersampled frame, before it is averaged back (4.5.6).
        # jit of the function itself (not a new lambda) so repeated calls reuse the compile.
        color = jax.jit(shade_voxels)(cam, color, out.depth, key=jax.random.key(0))
    color, depth = antialias(color, out.depth, args.aa)
    jax.block_until_ready(depth)
    seconds = time.perf_counter() - t0
    save_png(out_png, color)
    if depth_npy is not None:
        save_npy(depth_npy, depth)
    print(
        json.dumps(
            dict(
                out=str(args.out),
                depth=str(args.depth) if args.depth else None,
                renderer="reference-dda" if args.reference else "rle-planes",
                camera=",".join(f"{v:g}" for v in camera),
                lit=not args.unlit,
                seconds_incl_compile=round(seconds, 3),
                aa="{}x{}".format(*args.aa),
                hit_pixels=int(jnp.sum(jnp.isfinite(depth))),
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
        "trilinear) and their slice axis (z) becomes y.",
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
    r.add_argument("--refine", type=nonnegative_int, default=16,
                   help="exact re-walk steps for pixels whose ray met no sampled voxel "
                   "(0: off)")  # fmt: skip
    r.add_argument("--oversample", type=bounded_float(0.0, math.inf, open_interval=True),
                   default=2.0,
                   help="planes per border pixel (1 = thesis Eq. 4.4; 2 = default)")  # fmt: skip
    r.add_argument("--pool-size", type=positive_int, default=None,
                   help="drawn elements kept per frame (default 3 x oversample x W x H at "
                   "the --aa grid); a frame that needs more loses its farthest elements and "
                   "says so on stderr")  # fmt: skip
    r.add_argument("--buffer-size", type=positive_int, default=None,
                   help="drawn elements kept per plane (default max(64, max(W, H) / 2) at "
                   "the --aa grid; max(W, H) always suffices); as --pool-size")  # fmt: skip
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
