"""The ``jaxgfx`` command line: demo, render, sweep, info (+ module subcommands)."""

from __future__ import annotations

import argparse
import importlib
import json
import math
import platform
import sys
import time
from pathlib import Path

__all__ = ["main", "parse_size", "parse_floats"]

# Chapter modules add their subcommands through these optional modules, each
# exposing ``register(subparsers)``.
_PLUGINS = ("jaxgfx._cli_voxels", "jaxgfx._cli_terrain", "jaxgfx._cli_skin")


def parse_size(text: str) -> tuple[int, int]:
    """'WxH' -> (W, H), both positive."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 640x480, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return w, h


def parse_floats(n: int):
    def parse(text: str):
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers") from None
        if len(vals) != n or not all(math.isfinite(v) for v in vals):
            raise argparse.ArgumentTypeError(f"expected {n} finite comma-separated numbers")
        return vals

    return parse


def _machine() -> str:
    import os

    import jax

    devs = ", ".join(sorted({d.device_kind for d in jax.devices()}))
    cpu = platform.processor() or platform.machine()
    return f"{cpu}, {os.cpu_count()} cores; jax {jax.__version__} on {devs}"


def _time(fn, *args, repeats: int = 3):
    """(compile+first-run seconds, median steady seconds) of a jitted fn."""
    import jax

    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    steady = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        steady.append(time.perf_counter() - t0)
    steady.sort()
    return first, steady[len(steady) // 2], out


def _markdown_table(rows, headers) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for r in rows:
        lines.append("| " + " | ".join(str(r[h]) for h in headers) + " |")
    return "\n".join(lines) + "\n"


def cmd_demo(args) -> int:
    import jax

    from jaxgfx.compose import Frame, depth_image
    from jaxgfx.io import atomic_write, save_json, save_png
    from jaxgfx.scene import build_demo

    w, h = args.size
    out = Path(args.out)
    demo = build_demo(w, h, key=jax.random.key(args.seed))
    rows, frames = [], []
    for name, fn, fn_args, first in demo.passes:
        c, t, result = _time(fn, *fn_args)
        c = c if first is None else first
        if isinstance(result, Frame):  # other stages (terrain generation) feed a pass
            frames.append(result)
        rows.append(dict(stage=name, compile_s=c, ms=t * 1e3))
    c, t, frame = _time(demo.composite, frames)
    rows.append(dict(stage="depth composite + fog", compile_s=c, ms=t * 1e3))
    rows.append(
        dict(
            stage="frame total",
            compile_s=sum(r["compile_s"] for r in rows),
            ms=sum(r["ms"] for r in rows),
        )
    )
    save_png(out / "color.png", frame.color)
    save_png(out / "depth.png", depth_image(frame.depth))
    for r in rows:
        r["compile_s"] = f"{r['compile_s']:.2f}"
        r["ms"] = f"{r['ms']:.1f}"
    md = (
        f"# jaxgfx demo {w}x{h}\n\n{demo.description}\n\nmachine: {_machine()}\n\n"
        "compile_s: first call (trace + compile + run); ms: median of 3 later calls\n\n"
        + _markdown_table(rows, ["stage", "compile_s", "ms"])
    )
    with atomic_write(out / "timing.md") as tmp:
        tmp.write_text(md)
    save_json(
        out / "timing.json",
        dict(size=[w, h], scene=demo.description, machine=_machine(), stages=rows),
    )
    print(md)
    print(f"wrote {out / 'color.png'}, {out / 'depth.png'}, {out / 'timing.md'}")
    return 0


def _camera_for(mesh_vertices, args):
    import numpy as np

    from jaxgfx.camera import camera_from_degrees, look_at

    w, h = args.size
    lo, hi = mesh_vertices.min(0), mesh_vertices.max(0)
    center = 0.5 * (lo + hi)
    radius = float(np.linalg.norm(hi - lo)) * 0.5 + 1e-6
    if args.camera is not None:
        x, y, z, yaw, pitch = args.camera
        return camera_from_degrees(
            [x, y, z], yaw, pitch, 0.0, args.fov, w, h, radius * 1e-3, radius * 1e3
        )
    dist = radius / math.sin(math.radians(args.fov) / 2) * 1.1
    eye = center + dist * np.array([0.0, 0.35, 1.0]) / np.linalg.norm([0.0, 0.35, 1.0])
    return look_at(eye, center, args.fov, w, h, dist * 1e-3, dist * 10)


def cmd_render(args) -> int:
    import jax
    import numpy as np

    from jaxgfx.compose import background, composite
    from jaxgfx.io import load_mesh, mesh_arrays, save_npy, save_png
    from jaxgfx.scene import mesh_pass, render_mesh_pass

    m = load_mesh(args.mesh)
    v, f, c = mesh_arrays(m)
    cam = _camera_for(v, args)
    mp = mesh_pass(v, f, c)
    fn = jax.jit(
        lambda cam, mp: composite(
            [background(cam), render_mesh_pass(cam, mp, cull_backfaces=args.cull)]
        )
    )
    t0 = time.perf_counter()
    frame = jax.block_until_ready(fn(cam, mp))
    dt = time.perf_counter() - t0
    save_png(args.out, frame.color)
    if args.depth:
        save_npy(args.depth, np.asarray(frame.depth))
    cov = float(np.isfinite(np.asarray(frame.depth)).mean())
    print(json.dumps(dict(out=str(args.out), triangles=len(f), seconds=round(dt, 3), coverage=cov)))
    return 0


def contact_sheet(images, cols: int):
    """Tiles (N, H, W, 3) uint8 images into one grid image."""
    import numpy as np

    n, h, w, ch = images.shape
    rows = -(-n // cols)
    sheet = np.zeros((rows * h, cols * w, ch), images.dtype)
    for i in range(n):
        r, c = divmod(i, cols)
        sheet[r * h : (r + 1) * h, c * w : (c + 1) * w] = images[i]
    return sheet


def cmd_sweep(args) -> int:
    import numpy as np

    from jaxgfx.camera import orbit_cameras
    from jaxgfx.compose import background, composite, to_uint8
    from jaxgfx.io import load_mesh, mesh_arrays, save_png
    from jaxgfx.scene import mesh_pass, render_mesh_pass
    from jaxgfx.sweep import load_sweep, sweep

    if args.n <= 0:
        raise SystemExit("jaxgfx sweep: --n must be positive")
    m = load_mesh(args.mesh)
    v, f, c = mesh_arrays(m)
    w, h = args.size
    lo, hi = v.min(0), v.max(0)
    center = 0.5 * (lo + hi)
    radius = float(np.linalg.norm(hi - lo)) * 0.5 + 1e-6
    dist = radius / math.sin(math.radians(args.fov) / 2) * 1.1
    cams = orbit_cameras(
        center, dist, args.n, args.elevation, args.fov, w, h, dist * 1e-3, dist * 10
    )
    mp = mesh_pass(v, f, c)
    out = Path(args.out)

    def render_one(cam):
        fr = composite([background(cam), render_mesh_pass(cam, mp)])
        return {"color": to_uint8(fr.color), "depth": fr.depth}

    def write_frames(k, start, outputs):
        for i, img in enumerate(outputs["color"]):
            p = out / f"frame_{start + i:05d}.png"
            if not p.exists():
                save_png(p, img)

    summary = sweep(render_one, cams, out / "chunks", args.chunk, on_chunk=write_frames)
    allv = load_sweep(out / "chunks")
    save_png(out / "contact_sheet.png", contact_sheet(allv["color"], min(args.n, 6)))
    summary["frames"] = args.n
    print(json.dumps(summary))
    return 0


def cmd_info(args) -> int:
    import jax

    import jaxgfx

    info = dict(
        jaxgfx=jaxgfx.__version__,
        jax=jax.__version__,
        backend=jax.default_backend(),
        devices=[str(d) for d in jax.devices()],
        local_devices=jax.local_device_count(),
        processes=jax.process_count(),
        python=sys.version.split()[0],
        machine=_machine(),
    )
    print(json.dumps(info, indent=2))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="jaxgfx",
        description="Game-engine visualization in JAX (terrain, voxels, skinning).",
    )
    sub = p.add_subparsers(dest="command")

    d = sub.add_parser("demo", help="render the default scene; write color.png, depth.png, timing")
    d.add_argument("--size", type=parse_size, default=(640, 480), help="WxH (default 640x480)")
    d.add_argument("--out", default="demo", help="output directory (default demo/)")
    d.add_argument("--seed", type=int, default=0, help="random key for the procedural scene")
    d.set_defaults(func=cmd_demo)

    r = sub.add_parser("render", help="render a mesh file to PNG (+ depth .npy)")
    r.add_argument("mesh", help="PLY/OBJ/GLB/STL file")
    r.add_argument(
        "--camera",
        type=parse_floats(5),
        default=None,
        help="x,y,z,yaw,pitch (degrees; y up, yaw 0 looks along +z); default frames the mesh",
    )
    r.add_argument("--fov", type=float, default=45.0, help="vertical field of view, degrees")
    r.add_argument("--size", type=parse_size, default=(640, 480))
    r.add_argument("--out", default="frame.png")
    r.add_argument("--depth", default=None, help="write camera-space depth (+inf = empty) here")
    r.add_argument("--cull", action="store_true", help="cull back faces")
    r.set_defaults(func=cmd_render)

    s = sub.add_parser("sweep", help="orbit N cameras around a mesh (resumable)")
    s.add_argument("mesh")
    s.add_argument("--n", type=int, default=12, help="number of cameras")
    s.add_argument("--out", default="sweep")
    s.add_argument("--size", type=parse_size, default=(160, 120))
    s.add_argument("--fov", type=float, default=45.0)
    s.add_argument("--elevation", type=float, default=20.0, help="degrees above the horizon")
    s.add_argument("--chunk", type=int, default=4, help="cameras per chunk")
    s.set_defaults(func=cmd_sweep)

    i = sub.add_parser("info", help="jax version and devices")
    i.set_defaults(func=cmd_info)

    for name in _PLUGINS:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        mod.register(sub)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"jaxgfx {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
