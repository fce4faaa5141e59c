"""``jaxgfx demo``: render the default scene; write color.png, depth.png and a timing table."""

from __future__ import annotations

import argparse

from jaxgfx.cli.args import PIXEL_BYTES, check_image, check_out_dir, parse_size

__all__ = ["register", "run"]


def register(subparsers) -> None:
    """Adds ``demo`` to the CLI's subparsers."""
    d = subparsers.add_parser(
        "demo", help="render the default scene; write color.png, depth.png, timing"
    )
    d.add_argument("--size", type=parse_size, default=(640, 480), help="WxH (default 640x480)")
    d.add_argument("--out", default="demo", help="output directory (default demo/)")
    d.add_argument("--seed", type=int, default=0, help="random key for the procedural scene")
    d.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Renders every pass with one camera, composites them and writes the timing table."""
    out = check_out_dir("--out", args.out)
    check_image(args.size, 4 * PIXEL_BYTES)  # several passes + the composite
    import jax

    from jaxgfx._src.report import machine, markdown_table, time_jitted
    from jaxgfx.compose import Frame, depth_image
    from jaxgfx.io import atomic_write, save_json, save_png
    from jaxgfx.scene import build_demo

    w, h = args.size
    demo = build_demo(w, h, key=jax.random.key(args.seed))
    rows, frames = [], []
    for name, fn, fn_args, first in demo.passes:
        c, t, result = time_jitted(fn, *fn_args)
        c = c if first is None else first
        if isinstance(result, Frame):  # other stages (terrain generation) feed a pass
            frames.append(result)
        rows.append(dict(stage=name, compile_s=c, ms=t * 1e3))
    c, t, frame = time_jitted(demo.composite, frames)
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
    mach = machine()
    md = (
        f"# jaxgfx demo {w}x{h}\n\n{demo.description}\n\nmachine: {mach}\n\n"
        "compile_s: first call (trace + compile + run); ms: median of 3 later calls\n\n"
        + markdown_table(rows, ["stage", "compile_s", "ms"])
        + "\n"
    )
    with atomic_write(out / "timing.md") as tmp:
        tmp.write_text(md)
    save_json(
        out / "timing.json",
        dict(size=[w, h], scene=demo.description, machine=mach, stages=rows),
    )
    print(md)
    print(f"wrote {out / 'color.png'}, {out / 'depth.png'}, {out / 'timing.md'}")
    return 0
