"""``jaxgfx terrain``: render nested Clip-Box terrain around a viewer (thesis chapter 3)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from jaxgfx.cli.args import (
    PIXEL_BYTES,
    CliError,
    bounded_float,
    check_memory,
    check_out_file,
    input_errors,
    nonnegative_int,
    parse_floats,
    parse_fov,
    parse_ints,
    parse_size,
    positive_int,
    writing,
)

__all__ = [
    "register",
    "run",
    "make_terrain",
    "add_source_arguments",
    "check_source_args",
    "terrain_from_args",
    "color_heights",
    "snow_line",
    "map_points",
    "heightmap_eye",
    "levels_for_map",
    "DEFAULT_LEVELS",
    "HEIGHTMAP_YAW",
    "HEIGHTMAP_PITCH",
]

FUNCTIONS = ("csg", "xor", "saw", "sin", "heightmap:PATH")
MESH_SUFFIXES = (".ply", ".glb", ".obj", ".stl", ".off")
IMAGE_RELIEF_TEXT = "1/8"
"""jaxgfx.terrain.IMAGE_RELIEF in words (the help text is built without importing JAX)."""
VOXEL_BYTES = 64
"""Rough upper bound of the bytes one Clip-Box voxel costs (density, meshing, smoothing)."""
DEFAULT_LEVELS = 5
"""``--levels`` unless a height map's default view needs more to hold the whole map."""


def check_args(args) -> None:
    """Every check that needs no JAX: paths, levels, and the memory estimate."""
    check_out_file("--out", args.out, (".png",))
    if args.depth:
        check_out_file("--depth", args.depth, (".npy",))
    if args.mesh:
        check_out_file("--mesh", args.mesh, MESH_SUFFIXES)
    check_source_args(args)
    if args.mesh_level is not None and args.mesh is None:
        raise CliError("--mesh-level needs --mesh")
    # --levels left to the height map's view: checked again once the map says how many
    check_levels(args, DEFAULT_LEVELS if args.levels is None else args.levels)


def check_levels(args, levels: int) -> None:
    """Checks --mesh-level and the memory estimate for ``levels`` nested boxes."""
    n = args.resolution
    if args.mesh_level is not None:
        if args.mesh_level >= levels:
            raise CliError(
                f"--mesh-level must be in [0, {levels - 1}] with --levels {levels}, "
                f"got {args.mesh_level}"
            )
    w, h = args.size
    need = float(levels) * (n + 2) ** 3 * VOXEL_BYTES + float(w) * h * PIXEL_BYTES
    check_memory("--resolution", f"{n} (with --levels {levels}, --size {w}x{h})", need)


def check_source_args(args) -> None:
    """Checks the options :func:`add_source_arguments` adds (no JAX work): --resolution,
    --levels and the height-map-only flags."""
    n = args.resolution
    if n < 8 or n % 8:
        raise CliError(f"--resolution must be a multiple of 8 and >= 8, got {n}")
    from jaxgfx._src.terrain.clipbox import MAX_LEVEL, max_levels

    if args.levels is not None and args.levels > max_levels(n):
        raise CliError(
            f"--levels must be <= {max_levels(n)} with --resolution {n} (levels run 0..{MAX_LEVEL} "
            f"and the outer box must fit int32 world coordinates), got {args.levels}"
        )
    if not args.function.startswith("heightmap:"):
        for flag, given in (
            ("--cell", args.cell is not None),
            ("--vertical-scale", args.vertical_scale is not None),
            ("--wrap", args.wrap),
        ):
            if given:
                raise CliError(f"{flag} applies to --function heightmap:PATH only")


def terrain_from_args(args):
    """:func:`make_terrain` from the options :func:`add_source_arguments` adds.

    A height map's NODATA warning (voids filled) is printed as one line,
    ``jaxgfx CMD: warning: ...``; the JSON line reports the count and share too.
    """
    import warnings

    from jaxgfx.terrain import NodataWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", NodataWarning)
        terrain = make_terrain(
            args.function,
            seed=args.seed,
            vertical_scale=args.vertical_scale,
            cell=args.cell,
            wrap=args.wrap,
        )
    for w in caught:
        if issubclass(w.category, NodataWarning):
            print(f"jaxgfx {args.command}: warning: {w.message}", file=sys.stderr)
        else:  # any other warning as Python shows it
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return terrain


def make_terrain(
    spec: str,
    *,
    seed: int = 0,
    vertical_scale: float | None = None,
    cell: float | None = None,
    wrap: bool = False,
):
    """Terrain from a ``--function`` value: csg, xor, saw, sin or heightmap:PATH.

    A height map (GeoTIFF, SRTM .hgt, ESRI .asc, USGS .dem, image, .npy) is placed by
    :func:`jaxgfx.terrain.heightmap_terrain`: centred on the world origin, true
    proportions where the file gives units, a flat apron around it unless ``wrap``.
    """
    import jax

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
        return T.heightmap_terrain(path, cell=cell, vertical_scale=vertical_scale, wrap=wrap)
    raise ValueError(f"--function must be one of {', '.join(FUNCTIONS)}, got {spec!r}")


# Views that show each built-in function well: (viewer, (yaw, pitch), height range for
# the colours).  Height maps are framed whole instead (heightmap_eye).
VIEWS = {
    # rocks and arches over the ground plane, from just above it
    "csg": ((0, 40, 0), (35.0, -10.0), (-128.0, 256.0)),
    # the self-similar XOR pattern from high over its floor
    "xor": ((0, 430, 0), (45.0, -30.0), (0.0, 1000.0)),
    # near the floor of one gap between the diagonal slabs, looking along them
    "saw": ((0, 560, 0), (135.0, -10.0), (0.0, 1000.0)),
    # SIN is solid but for isolated pockets: the view from inside the solid shows their
    # lattice (the pockets' walls), so this default alone stands inside the ground
    "sin": ((0, 0, 0), (30.0, -10.0), (-30.0, 30.0)),
}
INSIDE_BY_DEFAULT = ("sin",)


HEIGHTMAP_YAW = 180.0
"""Every height map is seen looking north (towards row 0, -z), as a map is read..."""
HEIGHTMAP_PITCH = -35.0
"""...this many degrees downwards, from the nearest eye on that line of sight that shows
the whole map (:func:`heightmap_eye`): it stands south of the map's middle, above or
beyond its south edge, and looks across the map's middle."""
MAP_POINTS = 1 << 20
"""At most about this many samples of a height map are framed (a regular subset of a
larger map, its border and corners always in)."""


def map_points(terrain):
    """World points of a height map's surface: its samples (every one up to
    :data:`MAP_POINTS`, else a regular subset and every border sample) and its four outer
    corners, at true scale (NumPy, no JAX).

    Args:
        terrain: a :class:`jaxgfx.terrain.HeightmapTerrain`.

    Returns:
        (N, 3) float64 world points, y up.

    Raises:
        TypeError: ``terrain`` is not a height-map terrain.
    """
    import numpy as np

    from jaxgfx import terrain as T

    if not isinstance(terrain, T.HeightmapTerrain):
        raise TypeError(f"terrain must be a HeightmapTerrain, got {type(terrain).__name__}")
    m = terrain.mapping
    h = np.asarray(terrain.heights, np.float64)
    rows, cols = h.shape
    cx, cz = m.cells
    step = max(1, math.ceil(math.sqrt(rows * cols / MAP_POINTS)))
    r = np.union1d(np.arange(0, rows, step), [rows - 1])
    c = np.union1d(np.arange(0, cols, step), [cols - 1])
    rr, cc = (a.ravel() for a in np.meshgrid(r, c, indexing="ij"))
    border = np.concatenate(
        [
            np.stack([np.zeros(cols, int), np.arange(cols)], 1),
            np.stack([np.full(cols, rows - 1), np.arange(cols)], 1),
            np.stack([np.arange(rows), np.zeros(rows, int)], 1),
            np.stack([np.arange(rows), np.full(rows, cols - 1)], 1),
        ]
    )
    rr, cc = np.concatenate([rr, border[:, 0]]), np.concatenate([cc, border[:, 1]])
    x = m.origin[0] + (cc + 0.5) * cx
    z = m.origin[1] + (rr + 0.5) * cz
    pts = np.stack([x, m.base + h[rr, cc], z], 1)
    x0, x1 = m.origin[0], m.origin[0] + cols * cx
    z0, z1 = m.origin[1], m.origin[1] + rows * cz
    corners = np.array(
        [
            [x0, m.base + h[0, 0], z0],
            [x1, m.base + h[0, -1], z0],
            [x0, m.base + h[-1, 0], z1],
            [x1, m.base + h[-1, -1], z1],
        ]
    )
    return np.concatenate([pts, corners])


def _forward(yaw: float, pitch: float):
    """The unit direction a camera of ``yaw``, ``pitch`` (degrees) looks along (yaw 0 looks
    along +z, yaw 90 along +x, positive pitch up: :func:`jaxgfx.camera.camera_basis`)."""
    import numpy as np

    a, b = math.radians(yaw), math.radians(pitch)
    return np.array([math.sin(a) * math.cos(b), math.sin(b), math.cos(a) * math.cos(b)])


def heightmap_eye(terrain, yaw: float, pitch: float, fov: float, size):
    """The nearest eye looking at ``yaw``, ``pitch`` that shows the whole height map.

    The map's surface (:func:`map_points`) projects inside the frame with the CLI's margin
    (:data:`jaxgfx.cli.framing.MARGIN`), centred: :func:`jaxgfx.camera.frame_points`.

    Args:
        terrain: a :class:`jaxgfx.terrain.HeightmapTerrain`.
        yaw: degrees about +y (0 looks along +z).
        pitch: degrees, positive looks up.
        fov: vertical field of view, degrees.
        size: (W, H) pixels.

    Returns:
        (3,) float64 world position of the eye.

    Raises:
        ValueError: ``yaw`` or ``pitch`` is not finite, or ``pitch`` is not in (-90, 90).
    """
    import numpy as np

    from jaxgfx.cli.framing import framed_camera

    if not (math.isfinite(yaw) and math.isfinite(pitch)):
        raise ValueError(f"yaw and pitch must be finite, got {yaw}, {pitch}")
    if not -90.0 < pitch < 90.0:
        raise ValueError(f"pitch must be in (-90, 90) degrees, got {pitch}")
    cam = framed_camera(map_points(terrain), -_forward(yaw, pitch), fov, size)
    return np.asarray(cam.position, np.float64)


def levels_for_map(terrain, viewer, eye, resolution: int, at_least: int = DEFAULT_LEVELS) -> int:
    """The fewest nested boxes, ``at_least`` or more, that show a height map whole from
    ``eye``: the outer box, centred on ``viewer``, holds the whole map and its relief (plus
    the apron's fade and two outer voxels) and reaches twice as far as the map's farthest
    point from the eye, so that the flat apron around the map fades into the fog before the
    box ends; at most :func:`jaxgfx._src.terrain.clipbox.max_levels`.

    Args:
        terrain: a :class:`jaxgfx.terrain.HeightmapTerrain`.
        viewer: (3,) the boxes' centre, world voxels.
        eye: (3,) the eye, world voxels.
        resolution: voxels per box edge.
        at_least: the fewest levels returned.
    """
    import numpy as np

    from jaxgfx._src.terrain.clipbox import max_levels

    pts = map_points(terrain)
    hold = float(np.abs(pts - np.asarray(viewer, np.float64)).max())
    far = float(np.linalg.norm(pts - np.asarray(eye, np.float64), axis=1).max())
    levels = at_least
    while levels < max_levels(resolution):
        reach = resolution * (1 << (levels - 1)) // 2
        if reach >= max(hold + terrain.mapping.apron_fade + 2 * (1 << levels), 2 * far):
            break
        levels += 1
    return levels


def parse_snow_line(text: str) -> float | str | None:
    """'auto', 'none' or a fraction >= 0 of the height range (argparse type)."""
    word = text.strip().lower()
    if word in ("auto", "none"):
        return None if word == "none" else "auto"
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"expected auto, none or a number >= 0, got {text!r}")
    return value


def snow_line(args, terrain=None) -> float | None:
    """--snow-line, or the default: 0.8 of the relief, none for height maps without units
    (images, arrays: no altitude)."""
    if args.snow_line != "auto":
        return float(args.snow_line) if args.snow_line is not None else None
    mapping = getattr(terrain, "mapping", None)
    if mapping is not None and getattr(mapping, "metres_per_sample", None) is None:
        return None
    return 0.8


def color_heights(terrain, function: str) -> tuple[float, float]:
    """World y range of the colour bands: a height map's base to its top, else the
    range :data:`VIEWS` gives the function."""
    import numpy as np

    from jaxgfx import terrain as T

    if isinstance(terrain, T.HeightmapTerrain):
        relief = float(np.max(np.asarray(terrain.heights)))
        return (terrain.mapping.base, terrain.mapping.base + max(relief, 1.0))
    return VIEWS[function][2]


def _view(args, terrain):
    """(viewer, (yaw, pitch), world height range, eye) for ``args``, defaults by function.

    ``eye`` is the camera's position relative to ``viewer``, the Clip-Boxes' centre.  A
    height map's boxes are centred above its middle (unless ``--viewer``), and the eye
    stands where the whole map is in frame (:func:`heightmap_eye`) looking at
    :data:`HEIGHTMAP_YAW`, :data:`HEIGHTMAP_PITCH` (or ``--camera``); with ``--viewer`` the
    eye stands at the viewer.
    """
    import numpy as np

    from jaxgfx import terrain as T

    eye = np.zeros(3)
    if isinstance(terrain, T.HeightmapTerrain):
        viewer = T.default_viewer(terrain) if args.viewer is None else args.viewer
        camera = (HEIGHTMAP_YAW, HEIGHTMAP_PITCH) if args.camera is None else args.camera
        if args.viewer is None:
            with input_errors("--camera"):
                eye = heightmap_eye(terrain, *camera, args.fov, args.size)
            eye = eye - np.asarray(viewer, np.float64)
    else:
        viewer, camera, _ = VIEWS[args.function]
        viewer = viewer if args.viewer is None else args.viewer
    heights = color_heights(terrain, args.function)
    camera = camera if args.camera is None else tuple(args.camera)
    return tuple(int(v) for v in viewer), tuple(float(a) for a in camera), heights, eye


def run(args) -> int:
    """Builds the nested boxes around the viewer, renders them, prints one JSON line."""
    check_args(args)

    import jax
    import numpy as np

    from jaxgfx import terrain as T
    from jaxgfx.camera import camera_from_degrees
    from jaxgfx.io import save_mesh, save_npy, save_png
    from jaxgfx.raster import rasterize

    with input_errors():
        terrain = terrain_from_args(args)
    viewer, (yaw, pitch), heights, eye = _view(args, terrain)
    if args.levels is None:  # enough boxes to hold a height map seen whole
        frames_map = isinstance(terrain, T.HeightmapTerrain) and args.viewer is None
        world_eye = np.asarray(viewer, np.float64) + eye
        args.levels = (
            levels_for_map(terrain, viewer, world_eye, args.resolution)
            if frames_map
            else DEFAULT_LEVELS
        )
        check_levels(args, args.levels)
    if not (args.viewer is None and args.function in INSIDE_BY_DEFAULT):
        try:
            T.check_viewer(terrain, viewer, name="--viewer")
        except ValueError as err:
            if not args.allow_inside:
                raise CliError(f"{err} (--allow-inside renders it anyway)") from None
            print(f"jaxgfx terrain: warning: {err}", file=sys.stderr)
    pipe = T.ClipBoxPipeline(
        terrain, size=args.resolution, levels=args.levels, smoothing=args.smoothing
    )
    w, h = args.size
    t0 = time.perf_counter()
    state = pipe.init(np.asarray(viewer, np.int64))
    build_s = time.perf_counter() - t0
    levels = T.level_views(state)
    reach = args.resolution * (1 << (args.levels - 1)) // 2  # the outer box's half-width
    # seen from beyond the boxes, the fog and the far plane start at the eye, not the box
    span = reach + float(np.linalg.norm(eye))
    cam = camera_from_degrees(eye, yaw, pitch, 0.0, args.fov, w, h, 0.25, 8 * span)
    t0 = time.perf_counter()
    frame = T.render_terrain(
        cam,
        levels,
        viewer,
        height_range=heights,
        fog_distance=float(args.fog * span) if args.fog > 0 else None,
        snow_line=snow_line(args, terrain),
        rasterize_fn=jax.jit(rasterize),
    )
    jax.block_until_ready(frame)
    render_s = time.perf_counter() - t0
    with writing("--out", args.out):
        save_png(args.out, frame.color)
    report = {"function": args.function}
    if isinstance(terrain, T.HeightmapTerrain):
        report.update(terrain.mapping.to_dict())
    report.update(
        viewer=list(viewer),
        eye=[round(float(v), 2) for v in np.asarray(viewer) + eye],
        camera=[yaw, pitch],
        levels=args.levels,
        triangles=int(T.level_arrays(levels, viewer)[2].shape[0]),
        build_s=round(build_s, 3),
        render_s=round(render_s, 3),
        out=str(args.out),
    )
    if args.depth:
        with writing("--depth", args.depth):
            save_npy(args.depth, np.asarray(frame.depth))
        report["depth"] = str(args.depth)
    if args.mesh:
        mesh = T.mesh_to_trimesh(levels, viewer, level=args.mesh_level)
        with writing("--mesh", args.mesh):
            save_mesh(args.mesh, mesh.vertices, mesh.faces)
        report.update(mesh=str(args.mesh), mesh_triangles=len(mesh.faces))
    print(json.dumps(report))
    return 0


def add_source_arguments(p, *, levels_for_maps: bool = False) -> None:
    """The terrain-source, Clip-Box and shading options ``terrain`` and ``flythrough`` share:
    --function (with --seed, --vertical-scale, --cell, --wrap), --resolution, --levels,
    --smoothing, --fov, --snow-line and --fog; check them with :func:`check_source_args`.
    ``levels_for_maps`` leaves --levels None by default: as many as a height map's default
    view needs (:func:`levels_for_map`), else :data:`DEFAULT_LEVELS`."""
    p.add_argument(
        "--function",
        default="csg",
        help=f"one of {', '.join(FUNCTIONS)}; PATH is an elevation file (GeoTIFF .tif, SRTM "
        ".hgt named like N46W123.hgt, ESRI ASCII .asc, USGS .dem: true proportions) or a "
        "height image / .npy array (no units)",
    )
    p.add_argument(
        "--resolution", type=positive_int, default=64, help="N voxels per box edge (multiple of 8)"
    )
    p.add_argument(
        "--levels",
        type=positive_int,
        default=None if levels_for_maps else DEFAULT_LEVELS,
        help=f"number of nested boxes L >= 1 (default {DEFAULT_LEVELS}"
        + (
            "; for a height map without --viewer, enough that the outer box holds the whole map)"
            if levels_for_maps
            else ")"
        ),
    )
    p.add_argument(
        "--fov", type=parse_fov, default=60.0, help="vertical field of view, degrees in (0, 180)"
    )
    p.add_argument(
        "--smoothing", type=nonnegative_int, default=4, help="vertex-averaging iterations"
    )
    p.add_argument("--seed", type=int, default=0, help="key for the random CSG terrain")
    p.add_argument(
        "--vertical-scale",
        type=bounded_float(0.0, math.inf, open_interval=True),
        default=None,
        help="heightmap voxels per height unit (default: true proportions for elevation "
        "files; for images and .npy arrays, whose values carry no unit, the map's value "
        f"range becomes a relief of {IMAGE_RELIEF_TEXT} of its longer side, whatever the "
        "bit depth)",
    )
    p.add_argument(
        "--cell",
        type=bounded_float(0.0, math.inf, open_interval=True),
        default=None,
        help="heightmap voxels per sample along x (default 1; z follows the file's sample spacing)",
    )
    p.add_argument(
        "--wrap",
        action="store_true",
        help="tile the heightmap (default: beyond the map its edge fades into a flat "
        "apron at its border's median height)",
    )
    p.add_argument(
        "--snow-line",
        type=parse_snow_line,
        default="auto",
        help="snow above this fraction of the height range, 'none' or 'auto' "
        "(default: 0.8; none for image heightmaps, which carry no altitude)",
    )
    p.add_argument(
        "--fog",
        type=bounded_float(0.0, math.inf),
        default=1.0,
        help="fog distance in outer-box half-widths, plus the eye's distance from the "
        "viewer where the eye stands apart (1: the box edge fades into the horizon; 0: no "
        "fog, e.g. for views from above)",
    )


def register(subparsers) -> None:
    """Adds ``jaxgfx terrain`` to the CLI's subparsers."""
    p = subparsers.add_parser(
        "terrain",
        help="procedural volumetric terrain with nested Clip-Boxes (thesis ch. 3)",
        description=(
            "Samples a terrain function around an integer viewer into nested Clip-Boxes, "
            "converts them to welded, smoothed meshes and renders them shaded by slope and "
            "height, with fog to the horizon and a sky.  Prints one JSON line: for a height "
            "map the mapping (sample (r, c) with value v stands at x = origin_x + "
            "(c + 0.5) cell[0], z = origin_z + (r + 0.5) cell[1], y = base + (v - min) "
            "vertical_scale) and its scale (metres_per_sample [x, z] read from the file, "
            "metres_per_voxel [x, y, z] of the terrain built), the viewer, the camera, "
            "triangles and timings."
        ),
    )
    p.add_argument(
        "--viewer",
        type=parse_ints(3, "x,y,z"),
        default=None,
        help="x,y,z integer voxels (y up): the boxes' centre and the eye; default: a view "
        "that suits --function (height maps: the boxes centred above the map's middle, the "
        "eye where the whole map is in frame)",
    )
    p.add_argument(
        "--allow-inside",
        action="store_true",
        help="render even when --viewer is inside solid ground (warns instead of failing)",
    )
    p.add_argument("--out", default="terrain.png", help="output PNG")
    p.add_argument(
        "--depth", default=None, help="write camera-space depth (+inf = sky) to this .npy"
    )
    p.add_argument(
        "--camera",
        type=parse_floats(2, "yaw,pitch"),
        default=None,
        help="yaw,pitch in degrees (yaw 0 looks along +z); default suits --function. A "
        f"height map is seen at yaw {HEIGHTMAP_YAW:g} (north, towards row 0) and pitch "
        f"{HEIGHTMAP_PITCH:g} for every file; without --viewer the eye stands on a line of "
        "sight through the map, as near as the whole map in frame allows",
    )
    p.add_argument("--size", type=parse_size, default=(640, 480), help="WxH")
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
    add_source_arguments(p, levels_for_maps=True)
    p.set_defaults(func=run)
