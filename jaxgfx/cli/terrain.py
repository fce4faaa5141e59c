"""``jaxgfx terrain``: render nested Clip-Box terrain around a viewer (thesis chapter 3)."""

from __future__ import annotations

import math
import time

from jaxgfx.cli.args import (
    PIXEL_BYTES,
    CliError,
    bounded_float,
    check_memory,
    check_out_file,
    nonnegative_int,
    parse_floats,
    parse_fov,
    parse_ints,
    parse_size,
    positive_int,
)

__all__ = ["register", "run", "make_terrain"]

FUNCTIONS = ("csg", "xor", "saw", "sin", "heightmap:PATH")
MESH_SUFFIXES = (".ply", ".glb", ".obj", ".stl", ".off")
VOXEL_BYTES = 64
"""Rough upper bound of the bytes one Clip-Box voxel costs (density, meshing, smoothing)."""


def check_args(args) -> None:
    """Every check that needs no JAX: paths, levels, and the memory estimate."""
    check_out_file("--out", args.out, (".png",))
    if args.mesh:
        check_out_file("--mesh", args.mesh, MESH_SUFFIXES)
    n, levels = args.resolution, args.levels
    if n < 8 or n % 8:
        raise CliError(f"--resolution must be a multiple of 8 and >= 8, got {n}")
    if args.mesh_level is not None:
        if args.mesh is None:
            raise CliError("--mesh-level needs --mesh")
        if args.mesh_level >= levels:
            raise CliError(
                f"--mesh-level must be in [0, {levels - 1}] with --levels {levels}, "
                f"got {args.mesh_level}"
            )
    w, h = args.size
    need = float(levels) * (n + 2) ** 3 * VOXEL_BYTES + float(w) * h * PIXEL_BYTES
    check_memory("--resolution", f"{n} (with --levels {levels}, --size {w}x{h})", need)


def make_terrain(spec: str, *, seed: int = 0, vertical_scale: float | None = None, cell: int = 1):
    """Terrain from a ``--function`` value: csg, xor, saw, sin or heightmap:PATH."""
    import jax
    import numpy as np

    from jaxgfx import terrain as T

    if spec == "csg":
        return T.random_csg_terrain(key=jax.random.PRNGKey(seed))
    if spec == "xor":
        return T.XorTerrain()
    if spec == "saw":
        return T.SawTerrain()
    if spec == "sin":
        return T.SinTerrain()
    if spec.startswith("heightmap:"):
        path = spec.split(":", 1)[1]
        if not path:
            raise ValueError("--function heightmap:PATH needs a path")
        h = T.load_heightmap(path)
        rng = float(h.max() - h.min())
        if vertical_scale is None:
            # the relief spans an eighth of the map's width: hills, not needles
            vertical_scale = max(h.shape) * cell / 8.0 / rng if rng > 0 else 1.0
        base = -int(round(rng * vertical_scale / 2))
        return T.heightmap_terrain(
            np.asarray(h), vertical_scale=vertical_scale, cell=cell, base=base
        )
    raise ValueError(f"--function must be one of {', '.join(FUNCTIONS)}, got {spec!r}")


def run(args) -> int:
    """Builds the nested boxes around ``--viewer``, renders them, optionally exports the mesh."""
    check_args(args)

    import jax
    import numpy as np

    from jaxgfx import terrain as T
    from jaxgfx.camera import camera_from_degrees
    from jaxgfx.compose import background, composite
    from jaxgfx.io import save_mesh, save_png
    from jaxgfx.raster import rasterize

    terrain = make_terrain(
        args.function, seed=args.seed, vertical_scale=args.vertical_scale, cell=args.cell
    )
    pipe = T.ClipBoxPipeline(
        terrain, size=args.resolution, levels=args.levels, smoothing=args.smoothing
    )
    w, h = args.size
    viewer = np.asarray(args.viewer, np.int64)
    t0 = time.perf_counter()
    state = pipe.init(viewer)
    build_s = time.perf_counter() - t0
    levels = T.level_views(state)
    yaw, pitch = args.camera
    far = 4.0 * args.resolution * (1 << args.levels)
    cam = camera_from_degrees((0.0, 0.0, 0.0), yaw, pitch, 0.0, args.fov, w, h, 0.25, far)
    t0 = time.perf_counter()
    frame = T.render_levels(cam, levels, viewer, rasterize_fn=jax.jit(rasterize))
    img = composite([background(cam), frame]).color
    jax.block_until_ready(img)
    render_s = time.perf_counter() - t0
    out = args.out
    save_png(out, img)
    n_tri = int(T.level_arrays(levels, viewer)[2].shape[0])
    print(
        f"terrain {args.function}: {args.levels} levels of {args.resolution}^3 around "
        f"{tuple(int(v) for v in viewer)}: {n_tri} triangles; build {build_s:.2f} s "
        f"(with compilation), render {render_s:.2f} s -> {out}"
    )
    if args.mesh:
        mesh = T.mesh_to_trimesh(levels, viewer, level=args.mesh_level)
        save_mesh(args.mesh, mesh.vertices, mesh.faces)
        print(f"mesh ({len(mesh.faces)} triangles, relative to the viewer) -> {args.mesh}")
    return 0


def register(subparsers) -> None:
    """Adds ``jaxgfx terrain`` to the CLI's subparsers."""
    p = subparsers.add_parser(
        "terrain",
        help="procedural volumetric terrain with nested Clip-Boxes (thesis ch. 3)",
        description=(
            "Samples a terrain function around an integer viewer into nested Clip-Boxes, "
            "converts them to welded, smoothed meshes and renders the view along +z."
        ),
    )
    p.add_argument("--function", default="csg", help=f"one of {', '.join(FUNCTIONS)}")
    p.add_argument(
        "--viewer",
        type=parse_ints(3, "x,y,z"),
        default=(0, 24, 0),
        help="x,y,z integer voxels (y up)",
    )
    p.add_argument(
        "--resolution", type=positive_int, default=64, help="N voxels per box edge (multiple of 8)"
    )
    p.add_argument("--levels", type=positive_int, default=5, help="number of nested boxes L >= 1")
    p.add_argument("--out", default="terrain.png", help="output PNG")
    p.add_argument(
        "--camera",
        type=parse_floats(2, "yaw,pitch"),
        default=(0.0, -15.0),
        help="yaw,pitch in degrees",
    )
    p.add_argument("--size", type=parse_size, default=(640, 480), help="WxH")
    p.add_argument(
        "--fov", type=parse_fov, default=60.0, help="vertical field of view, degrees in (0, 180)"
    )
    p.add_argument(
        "--mesh",
        default=None,
        help=f"export the mesh, the levels welded into one surface ({', '.join(MESH_SUFFIXES)})",
    )
    p.add_argument(
        "--mesh-level",
        type=nonnegative_int,
        default=None,
        help="export only this level, 0 (innermost) .. L-1",
    )
    p.add_argument(
        "--smoothing", type=nonnegative_int, default=4, help="vertex-averaging iterations"
    )
    p.add_argument("--seed", type=int, default=0, help="key for the random CSG terrain")
    p.add_argument(
        "--vertical-scale",
        type=bounded_float(0.0, math.inf, open_interval=True),
        default=None,
        help="heightmap voxels per unit (default: relief an eighth of the map's width)",
    )
    p.add_argument("--cell", type=positive_int, default=1, help="heightmap voxels per pixel")
    p.set_defaults(func=run)
