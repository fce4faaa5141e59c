"""``jaxgfx flythrough``: fly a camera over Clip-Box terrain while a geometry thread
follows it (thesis 3.5.4, Fig. 3.1 and 3.18).

The render loop (this thread) moves the camera along a path, tells the
:class:`jaxgfx.terrain.GeometryWorker` where it is, swaps in the newest complete set of
levels and draws them with :func:`jaxgfx.terrain.render_terrain`.  The frames become an
animated GIF (or MP4 with imageio's ffmpeg plugin); a per-frame table (render ms,
triangles, boxes the worker updated since the last frame and their reuse) is written
beside it as Markdown and JSON.
"""

from __future__ import annotations

import functools
import importlib.util
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from jaxgfx.cli.args import (
    PIXEL_BYTES,
    CliError,
    bounded_float,
    check_image,
    check_memory,
    check_out_file,
    input_errors,
    parse_size,
    positive_int,
    writing,
)
from jaxgfx.cli.terrain import (
    INSIDE_BY_DEFAULT,
    VIEWS,
    VOXEL_BYTES,
    add_source_arguments,
    check_source_args,
    color_heights,
    snow_line,
    terrain_from_args,
)

__all__ = [
    "register",
    "run",
    "parse_path",
    "default_path",
    "path_frames",
    "check_clearance",
    "fly",
    "MARGIN",
]

MARGIN = 2
"""Voxels of air the camera keeps around it: above the ground of a height map within
one voxel sideways, and in every direction for other terrains."""
OUT_SUFFIXES = (".gif", ".mp4")


def parse_path(text: str) -> np.ndarray:
    """'x,y,z,x,y,z,...' -> (K, 3) float64 waypoints, K >= 2 (argparse type)."""
    import argparse

    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if not vals or len(vals) % 3 or not all(math.isfinite(v) for v in vals):
        raise argparse.ArgumentTypeError(
            f"expected x,y,z,x,y,z,... (finite numbers, a multiple of 3), got {text!r}"
        )
    pts = np.asarray(vals, np.float64).reshape(-1, 3)
    if np.abs(pts).max() > 2**30:  # the boxes around the camera must fit in int32 too
        raise argparse.ArgumentTypeError(f"waypoints must be within +-2^30 voxels, got {text!r}")
    if len(pts) < 2 or not np.any(np.abs(np.diff(pts, axis=0)) > 0):
        raise argparse.ArgumentTypeError(f"needs at least two different waypoints, got {text!r}")
    return pts


def reach(args) -> int:
    """The outer Clip-Box's half-width in voxels."""
    return args.resolution * (1 << (args.levels - 1)) // 2


def _heightmap_clear_y(terrain, x, z, radius: float) -> np.ndarray:
    """Highest ground within ``radius`` voxels of each (x, z) (a 5x5 footprint)."""
    from jaxgfx import terrain as T

    o = np.linspace(-radius, radius, 5)
    dx, dz = (a.ravel() for a in np.meshgrid(o, o))
    g = T.ground_height(terrain, x[:, None] + dx, z[:, None] + dz)
    return np.asarray(g, np.float64).max(axis=1)


@functools.cache
def _solid_fn():
    """One jitted ``vmap(terrain)`` for every terrain (a pytree argument), compiled once
    per terrain structure and point count."""
    import jax

    return jax.jit(lambda terrain, q: jax.vmap(terrain)(q))


def _air_cube(terrain, points: np.ndarray, margin: int) -> np.ndarray:
    """(P,) bool: every voxel within ``margin`` (Chebyshev) of each integer point is air."""
    import jax.numpy as jnp

    o = np.arange(-margin, margin + 1)
    cube = np.stack(np.meshgrid(o, o, o, indexing="ij"), -1).reshape(-1, 3)
    q = (points.astype(np.int64)[:, None, :] + cube).reshape(-1, 3)
    solid = _solid_fn()(terrain, jnp.asarray(q, jnp.int32))
    return np.asarray(~np.asarray(solid).reshape(len(points), -1).any(axis=1))


def default_path(terrain, function: str, half_width: int) -> tuple[np.ndarray, float]:
    """Waypoints (K, 3) and pitch (degrees) of a flight that suits the terrain.

    A height map is crossed from south to north (towards row 0, like the ``terrain``
    view) along a gentle S-curve through the centre, over 76 % of its length, at a
    quarter of its relief (at least 8 voxels, at most a quarter of ``half_width``: with
    small boxes the ground stays inside them and the fog) above the highest ground
    near the track, looking ahead and 15 degrees down.  Other functions fly from their ``terrain``
    view along its heading for one outer-box half-width, lifted where the track would
    pass within :data:`MARGIN` voxels of solid ground.
    """
    from jaxgfx import terrain as T

    if isinstance(terrain, T.HeightmapTerrain):
        m = terrain.mapping
        w, d = m.shape[1] * m.cells[0], m.shape[0] * m.cells[1]
        cx, cz = m.origin[0] + w / 2, m.origin[1] + d / 2
        t = np.linspace(0.0, 1.0, 65)
        x = cx + 0.12 * w * np.sin(2 * np.pi * t)
        z = cz + d * (0.38 - 0.76 * t)
        relief = float(np.max(np.asarray(terrain.heights)))
        clearance = min(max(8.0, 0.25 * relief), max(MARGIN + 1.0, half_width / 4))
        step = float(np.hypot(np.diff(x), np.diff(z)).max())
        y = _heightmap_clear_y(terrain, x, z, max(4.0, step)) + clearance
        # a running max then a narrower running mean: smooth, and still >= each
        # sample's own requirement (every averaged value is a max over its window)
        k = 4
        pad = np.pad(y, k, mode="edge")
        y = np.max(np.lib.stride_tricks.sliding_window_view(pad, 2 * k + 1), axis=1)
        pad = np.pad(y, k, mode="edge")
        y = np.mean(np.lib.stride_tricks.sliding_window_view(pad, 2 * k + 1), axis=1)
        return np.stack([x, y, z], -1), -15.0
    (vx, vy, vz), (yaw, pitch), _ = VIEWS[function]
    a = math.radians(yaw)
    t = np.linspace(0.0, 1.0, 33)[:, None]
    pts = np.asarray([vx, vy, vz], np.float64) + t * half_width * np.array(
        [math.sin(a), 0.0, math.cos(a)]
    )
    if function not in INSIDE_BY_DEFAULT:
        # lift the whole track until every waypoint (and the frames between, checked
        # again later) has MARGIN voxels of air around it
        for _ in range(64):
            if _air_cube(terrain, np.floor(pts), MARGIN + 1).all():
                break
            pts[:, 1] += 4.0
    return pts, float(pitch)


def path_frames(waypoints: np.ndarray, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera positions (frames, 3) evenly spaced by arc length along the polyline
    ``waypoints``, and yaws (frames,) in degrees along the smoothed horizontal heading
    (yaw 0 looks along +z, 90 along +x)."""
    wp = np.asarray(waypoints, np.float64)
    seg = np.linalg.norm(np.diff(wp, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    u = np.linspace(0.0, s[-1], frames)
    pos = np.stack([np.interp(u, s, wp[:, i]) for i in range(3)], -1)
    # the heading over a window of a tenth of the track, so corners turn smoothly
    dense = np.linspace(0.0, s[-1], 256)
    dp = np.stack([np.interp(dense, s, wp[:, i]) for i in range(3)], -1)
    k = 13
    ahead = dp[np.minimum(np.arange(256) + k, 255)] - dp[np.maximum(np.arange(256) - k, 0)]
    yaw_dense = np.unwrap(np.arctan2(ahead[:, 0], ahead[:, 2]))
    yaw = np.degrees(np.interp(u, dense, yaw_dense))
    return pos, yaw


def check_clearance(terrain, positions: np.ndarray, *, option: str = "--path") -> None:
    """Raises :class:`CliError` naming ``option`` at the first frame whose camera has
    less than :data:`MARGIN` voxels of air: under a height map's ground (within one voxel
    sideways), or next to solid voxels of any other terrain."""
    from jaxgfx import terrain as T

    if isinstance(terrain, T.HeightmapTerrain):
        g = _heightmap_clear_y(terrain, positions[:, 0], positions[:, 2], 1.0)
        bad = np.flatnonzero(positions[:, 1] - g < MARGIN)
        if len(bad):
            i = int(bad[0])
            raise CliError(
                f"{option}: frame {i} at {tuple(round(float(v), 1) for v in positions[i])} is "
                f"{positions[i, 1] - g[i]:.1f} voxels above the ground; keep >= {MARGIN} "
                f"(y >= {math.ceil(g[i] + MARGIN)} there)"
            )
        return
    ok = _air_cube(terrain, np.floor(positions), MARGIN)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        raise CliError(
            f"{option}: frame {i} at {tuple(round(float(v), 1) for v in positions[i])} is "
            f"within {MARGIN} voxels of solid ground"
        )


def _wait_for_geometry(worker, pipe, viewer, timeout_s: float = 600.0) -> dict:
    """The worker's buffer once it has followed ``viewer`` (no box would move)."""
    t0 = time.perf_counter()
    while True:
        # A caught-up state makes no further update, so the buffer acquired next is its own.
        g0, state = worker.published()
        caught_up = not pipe.plan(state, viewer)
        buf = worker.acquire()
        if caught_up and int(buf["stamp"][1]) == g0:
            return buf
        if time.perf_counter() - t0 > timeout_s:
            raise RuntimeError("the geometry worker did not follow the camera in time")
        time.sleep(0.002)


def fly(
    pipe,
    positions: np.ndarray,
    yaws: np.ndarray,
    pitch: float,
    *,
    size: tuple[int, int],
    fov: float,
    height_range: tuple[float, float],
    fog_distance: float | None,
    snow_line: float | None,
    wait: bool = False,
    progress: bool | None = None,
) -> tuple[np.ndarray, list[dict]]:
    """Flies the camera along ``positions`` with a :class:`GeometryWorker` following it.

    Args:
        pipe: the :class:`jaxgfx.terrain.ClipBoxPipeline`.
        positions: (F, 3) float world camera positions (voxels, y up).
        yaws: (F,) degrees; ``pitch`` degrees for every frame.
        size: (W, H) pixels; ``fov`` vertical degrees.
        height_range, fog_distance, snow_line: as in :func:`jaxgfx.terrain.render_terrain`.
        wait: draw each frame only once the worker has followed the camera (a film that
            does not depend on the machine's speed; the time waited is ``wait_ms``).
        progress: tqdm bar on stderr (None: only on a terminal).
    Returns:
        ``(frames (F, H, W, 3) uint8, rows)``; a row per frame: ``frame``, ``ms`` (swap,
        colours, rasterization, shading), ``wait_ms``, ``triangles``, ``boxes_updated`` (Clip-Box
        updates in the geometry swapped in for this frame), ``reuse_pct`` (their mean
        reused voxels, None without updates) and ``generation``.
    """
    import jax
    from tqdm.auto import tqdm

    from jaxgfx import terrain as T
    from jaxgfx.camera import camera_from_degrees
    from jaxgfx.raster import rasterize

    w, h = size
    far = 16.0 * pipe.size * (1 << (pipe.levels - 1))
    raster = jax.jit(rasterize)
    anchors = np.floor(positions).astype(np.int64)

    def draw(buf, i):
        cam = camera_from_degrees(
            tuple(positions[i] - anchors[i]), float(yaws[i]), pitch, 0.0, fov, w, h, 0.25, far
        )
        frame = T.render_terrain(
            cam,
            buf["levels"],
            anchors[i],
            height_range=height_range,
            fog_distance=fog_distance,
            snow_line=snow_line,
            rasterize_fn=raster,
        )
        return np.round(np.clip(np.asarray(frame.color), 0.0, 1.0) * 255).astype(np.uint8)

    worker = T.GeometryWorker(pipe, anchors[0])
    draw(worker.acquire(), 0)  # compiles the first shapes outside the timings
    worker.start()
    frames = np.zeros((len(positions), h, w, 3), np.uint8)
    rows: list[dict] = []
    shown = 0
    quiet = not sys.stderr.isatty() if progress is None else not progress
    bar = tqdm(total=len(positions), desc="flythrough", unit="frame", disable=quiet)
    try:
        for i in range(len(positions)):
            worker.set_viewer(anchors[i])
            t0 = time.perf_counter()
            if wait:
                _wait_for_geometry(worker, pipe, anchors[i])
            t1 = time.perf_counter()
            wait_ms = 1e3 * (t1 - t0)
            t0 = t1
            buf = worker.acquire()
            gen = int(buf["stamp"][1])
            frames[i] = draw(buf, i)
            ms = 1e3 * (time.perf_counter() - t0)
            updates = [s for stats in worker.stats[shown:gen] for s in stats.values()]
            shown = gen
            tris = sum(int(lv["visible"].sum()) for lv in buf["levels"])
            reuse = 100.0 * float(np.mean([s["reused"] for s in updates])) if updates else None
            rows.append(
                dict(
                    frame=i,
                    ms=round(ms, 2),
                    wait_ms=round(wait_ms, 2),
                    triangles=tris,
                    boxes_updated=len(updates),
                    reuse_pct=None if reuse is None else round(reuse, 1),
                    generation=gen,
                )
            )
            bar.update(1)
    finally:
        bar.close()
        worker.stop()
    return frames, rows


def check_args(args) -> tuple[Path, Path, Path]:
    """Every check that needs no JAX; returns the output, Markdown and JSON table paths."""
    out = check_out_file("--out", args.out, OUT_SUFFIXES)
    if out.suffix.lower() == ".mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
        raise CliError(
            f"--out {str(out)!r}: writing MP4 needs imageio's ffmpeg plugin "
            "(pip install imageio-ffmpeg); or write a .gif"
        )
    md = check_out_file("--out", out.with_suffix(".md"), (".md",))
    js = check_out_file("--out", out.with_suffix(".json"), (".json",))
    if args.still:
        check_out_file("--still", args.still, (".png",))
    check_source_args(args)
    n, levels = args.resolution, args.levels
    w, h = args.size
    check_image(args.size, PIXEL_BYTES)
    need = float(levels) * (n + 2) ** 3 * VOXEL_BYTES * 2  # the worker's two buffers
    need += float(w) * h * (PIXEL_BYTES + 3 * args.frames)
    check_memory(
        "--frames",
        f"{args.frames} (with --size {w}x{h}, --resolution {n}, --levels {levels})",
        need,
    )
    return out, md, js


def _table_markdown(args, rows: list[dict], summary: dict) -> str:
    lines = [
        f"# jaxgfx flythrough: {args.function}",
        "",
        f"{args.frames} frames, {args.size[0]}x{args.size[1]}, N = {args.resolution}, "
        f"{args.levels} levels; geometry worker {'waited for' if args.wait else 'concurrent'}. "
        f"Median {summary['frame_ms_median']} ms/frame, {summary['box_updates']} box updates, "
        f"mean reuse {summary['reuse_pct_mean']} %.",
        "",
        "| frame | ms render | ms waiting for geometry | triangles | boxes updated | reuse % |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        reuse = "" if r["reuse_pct"] is None else f"{r['reuse_pct']:.1f}"
        lines.append(
            f"| {r['frame']} | {r['ms']:.1f} | {r['wait_ms']:.1f} | {r['triangles']} "
            f"| {r['boxes_updated']} | {reuse} |"
        )
    return "\n".join(lines) + "\n"


def run(args) -> int:
    """Builds the path, flies it, writes the film, the tables and one JSON line."""
    out, md_path, js_path = check_args(args)

    import imageio.v3 as iio

    from jaxgfx import terrain as T
    from jaxgfx.io import atomic_write, save_json, save_png

    with input_errors():
        terrain = terrain_from_args(args)
    if args.function not in VIEWS and not isinstance(terrain, T.HeightmapTerrain):
        raise CliError(f"--function {args.function!r} has no default view")
    if args.path is not None:
        waypoints, pitch = args.path, -15.0
    else:
        waypoints, pitch = default_path(terrain, args.function, reach(args))
    pitch = pitch if args.pitch is None else args.pitch
    positions, yaws = path_frames(waypoints, args.frames)
    if args.path is not None or args.function not in INSIDE_BY_DEFAULT:
        try:
            check_clearance(terrain, positions, option="--path")
        except CliError as err:
            if not args.allow_inside:
                raise CliError(f"{err} (--allow-inside flies it anyway)") from None
            print(f"jaxgfx flythrough: warning: {err}", file=sys.stderr)
    pipe = T.ClipBoxPipeline(
        terrain, size=args.resolution, levels=args.levels, smoothing=args.smoothing
    )
    t0 = time.perf_counter()
    frames, rows = fly(
        pipe,
        positions,
        yaws,
        pitch,
        size=tuple(args.size),
        fov=args.fov,
        height_range=color_heights(terrain, args.function),
        fog_distance=float(args.fog * reach(args)) if args.fog > 0 else None,
        snow_line=snow_line(args, terrain),
        wait=args.wait,
    )
    total_s = time.perf_counter() - t0
    ms = np.asarray([r["ms"] for r in rows])
    reuse = [r["reuse_pct"] for r in rows if r["reuse_pct"] is not None]
    summary = dict(
        function=args.function,
        frames=args.frames,
        size=list(args.size),
        path_start=[round(float(v), 2) for v in positions[0]],
        path_end=[round(float(v), 2) for v in positions[-1]],
        pitch=pitch,
        frame_ms_median=round(float(np.median(ms)), 1),
        frame_ms_max=round(float(ms.max()), 1),
        wait_ms_total=round(float(sum(r["wait_ms"] for r in rows)), 1),
        box_updates=int(sum(r["boxes_updated"] for r in rows)),
        reuse_pct_mean=round(float(np.mean(reuse)), 1) if reuse else None,
        total_s=round(total_s, 2),
    )
    with writing("--out", out), atomic_write(out) as tmp:
        if out.suffix.lower() == ".gif":
            iio.imwrite(tmp, frames, extension=".gif", duration=1000.0 / args.fps, loop=0)
        else:
            iio.imwrite(tmp, frames, extension=".mp4", fps=args.fps)
    with writing("--out", md_path):
        with atomic_write(md_path) as tmp:
            tmp.write_text(_table_markdown(args, rows, summary))
        save_json(js_path, dict(summary, rows=rows))
    summary.update(out=str(out), table=[str(md_path), str(js_path)])
    if args.still:
        with writing("--still", args.still):
            save_png(args.still, frames[len(frames) // 2])
        summary["still"] = str(args.still)
    print(json.dumps(summary))
    return 0


def register(subparsers) -> None:
    """Adds ``jaxgfx flythrough`` to the CLI's subparsers."""
    p = subparsers.add_parser(
        "flythrough",
        help="fly a camera over Clip-Box terrain, geometry thread following (thesis 3.5.4)",
        description=(
            "Flies a camera along a path over a terrain while the geometry worker moves the "
            "nested Clip-Boxes after it, and writes the frames as an animated GIF (or MP4), "
            "a per-frame table (render ms, triangles, boxes updated, reuse %) as Markdown and "
            "JSON beside it, and one JSON line with the summary."
        ),
    )
    p.add_argument(
        "--out",
        default="flythrough.gif",
        help="the film, .gif or .mp4 (MP4 needs imageio-ffmpeg); the tables go beside it "
        "as .md and .json",
    )
    p.add_argument(
        "--path",
        type=parse_path,
        default=None,
        help="x,y,z,x,y,z,... world waypoints (voxels, y up), flown at even speed looking "
        "along the track; default: a flight that suits --function (height maps: across "
        "the map, above the ground)",
    )
    p.add_argument("--frames", type=positive_int, default=90, help="number of frames")
    p.add_argument(
        "--fps",
        type=bounded_float(0.0, 100.0, open_interval=True),
        default=15.0,
        help="frames per second of the film",
    )
    p.add_argument("--size", type=parse_size, default=(320, 240), help="WxH")
    p.add_argument(
        "--pitch",
        type=bounded_float(-89.0, 89.0),
        default=None,
        help="camera pitch in degrees (negative looks down); default suits --function",
    )
    p.add_argument(
        "--no-wait",
        dest="wait",
        action="store_false",
        help="draw each frame at once with the newest geometry the worker has finished "
        "(the concurrent loop of Fig. 3.18; on a slow machine the boxes lag behind the "
        "camera); default: wait until it has followed the camera, the same film anywhere",
    )
    p.add_argument("--still", default=None, help="also write the middle frame to this PNG")
    p.add_argument(
        "--allow-inside",
        action="store_true",
        help="fly even where --path passes within 2 voxels of solid ground (warns)",
    )
    add_source_arguments(p)
    p.set_defaults(func=run)
