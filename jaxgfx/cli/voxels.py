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
import time
from pathlib import Path

from jaxgfx.cli.args import (
    CliError,
    bounded_float,
    check_image,
    check_memory,
    check_out_file,
    nonnegative_int,
    parse_aa,
    parse_floats,
    parse_fov,
    parse_size,
    positive_int,
)

__all__ = ["register", "run_voxelize", "run_render_voxels", "load_input"]

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


def load_input(path: str, resolution: int | None, iso: float | None, seed: int = 0):
    """Reads any supported input as surface :class:`~jaxgfx.raycast.Voxels`.

    ``tree`` (literally) makes a procedural tree from ``seed``.
    """
    import jax
    import numpy as np

    from jaxgfx import raycast as V

    p = Path(path)
    ext = p.suffix.lower()
    native = ext in (".vxl", ".kv6", ".mhd", ".nhdr", ".nrrd")
    if native and resolution is not None:
        raise ValueError(f"--resolution applies to meshes and trees, not to {ext} files")
    if ext == ".vxl":
        return V.load_vxl(str(p))
    if ext == ".kv6":
        return V.load_kv6(str(p))
    if ext in (".mhd", ".nhdr", ".nrrd"):
        vol, _ = V.load_volume(str(p))
        if iso is None:
            lo, hi = float(vol.min()), float(vol.max())
            iso = 0.5 * (lo + hi)
        return V.volume_to_voxels(vol, iso, up_axis=2)
    if resolution is None:
        raise ValueError("--resolution is required for meshes and trees")
    if path == "tree":
        return V.procedural_tree(resolution, key=jax.random.key(seed))
    from jaxgfx.io import load_mesh

    mesh = load_mesh(p)
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
    vox = load_input(args.input, args.resolution, args.iso, args.seed)
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
    )
    print(json.dumps(line))
    return 0


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
    from jaxgfx.post import antialias

    vox = RC.load_scene(args.scene)
    check_levels(args.levels, max(vox.shape), "scene's largest axis")
    x, y, z, yaw, pitch = args.camera
    w, h = args.size
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
        )
        out = fn(
            RC.as_jax(rle),
            cam,
            settings=settings,
            lod_distance=args.lod if args.lod > 0 else jnp.inf,
        )
        stats = {k: int(v) for k, v in out.stats.items()}
    color, depth = antialias(out.color, out.depth, args.aa)
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
        "(thesis 4.3, 4.4.6). " + _CONVENTIONS,
    )
    p.add_argument("input", help="mesh (.ply/.obj/...), volume header (.mhd/.nhdr), "
                   ".vxl, .kv6, or the word 'tree'")  # fmt: skip
    p.add_argument("--resolution", type=positive_int, default=None,
                   help="grid size of the longest axis (meshes and trees only)")  # fmt: skip
    p.add_argument("--iso", type=float, default=None,
                   help="iso threshold for volumes (default: middle of the range)")  # fmt: skip
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
        "pitch in degrees (positive looks up). The --depth file holds the distance along "
        "the view axis in voxel units, +inf where nothing was hit.",
    )
    r.add_argument("scene", help="scene .npz from 'jaxgfx voxelize'")
    r.add_argument(
        "--camera", type=parse_floats(5, "x,y,z,yaw,pitch"), required=True, help="x,y,z,yaw,pitch"
    )
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
                   "(0: level 0 only)")  # fmt: skip
    r.add_argument("--refine", type=nonnegative_int, default=16,
                   help="exact re-walk steps for pixels whose ray met no sampled voxel "
                   "(0: off)")  # fmt: skip
    r.add_argument("--oversample", type=bounded_float(0.0, math.inf, open_interval=True),
                   default=2.0,
                   help="planes per border pixel (1 = thesis Eq. 4.4; 2 = default)")  # fmt: skip
    r.add_argument("--thesis", action="store_true",
                   help="the thesis method alone: 1 plane per border pixel, nearest "
                   "texel, no re-walk")  # fmt: skip
    r.add_argument("--aa", type=parse_aa, default=(1, 1),
                   help="anti-aliasing 1x1 (off), 2x1 (thesis: pixels half as wide) or 2x2; "
                   "the frame is rendered at the finer grid and averaged back to --size, "
                   "the depth is the nearest sample")  # fmt: skip
    r.add_argument("--out", required=True, help="output PNG (.png)")
    r.add_argument("--depth", default=None, help="optional depth (.npy)")
    r.add_argument("--reference", action="store_true",
                   help="use the per-pixel 3-D DDA reference renderer instead")  # fmt: skip
    r.set_defaults(func=run_render_voxels)
