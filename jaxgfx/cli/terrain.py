"""``jaxgfx terrain``: render nested Clip-Box terrain around a viewer (thesis chapter 3)."""

from __future__ import annotations

import time
from pathlib import Path

from jaxgfx.cli.args import parse_floats, parse_ints, parse_size

__all__ = ["register", "run", "make_terrain"]

FUNCTIONS = ("csg", "xor", "saw", "sin", "heightmap:PATH")


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
    out = Path(args.out)
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
        "--resolution", type=int, default=64, help="N voxels per box edge (multiple of 8)"
    )
    p.add_argument("--levels", type=int, default=5, help="number of nested boxes L >= 1")
    p.add_argument("--out", default="terrain.png", help="output PNG")
    p.add_argument(
        "--camera",
        type=parse_floats(2, "yaw,pitch"),
        default=(0.0, -15.0),
        help="yaw,pitch in degrees",
    )
    p.add_argument("--size", type=parse_size, default=(640, 480), help="WxH")
    p.add_argument("--fov", type=float, default=60.0, help="vertical field of view, degrees")
    p.add_argument("--mesh", default=None, help="export the mesh (.ply, .glb, .obj)")
    p.add_argument("--mesh-level", type=int, default=None, help="export only this level")
    p.add_argument("--smoothing", type=int, default=4, help="vertex-averaging iterations")
    p.add_argument("--seed", type=int, default=0, help="key for the random CSG terrain")
    p.add_argument("--vertical-scale", type=float, default=None, help="heightmap voxels per unit")
    p.add_argument("--cell", type=int, default=1, help="heightmap voxels per pixel")
    p.set_defaults(func=run)
