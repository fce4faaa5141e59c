"""``jaxgfx demo``: render the default scene; write color.png, depth.png and a timing table."""

from __future__ import annotations

import argparse

from jaxgfx.cli.args import (
    PIXEL_BYTES,
    CliError,
    check_image,
    check_memory,
    check_out_dir,
    nonnegative_int,
    parse_size,
    writing,
)

__all__ = ["register", "run"]

MAX_FRAMES = 240
"""The most frames ``demo.gif`` takes (ten seconds of walking at 24 frames per second)."""


def register(subparsers) -> None:
    """Adds ``demo`` to the CLI's subparsers."""
    d = subparsers.add_parser(
        "demo", help="render the default scene; write color.png, depth.png, timing"
    )
    d.add_argument("--size", type=parse_size, default=(640, 480), help="WxH (default 640x480)")
    d.add_argument("--out", default="demo", help="output directory (default demo/)")
    d.add_argument("--seed", type=int, default=0, help="random key for the procedural scene")
    d.add_argument(
        "--data",
        default=None,
        help="shared data folder with terrain/, voxlap/, rigs/ (default: $JAXGFX_DATA, else "
        "../shared/data from the current directory if it exists, else the procedural scene)",
    )
    d.add_argument(
        "--frames",
        type=nonnegative_int,
        default=8,
        help="frames of the walking animation in demo.gif, 0..240 (0: no GIF; default 8)",
    )
    d.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Renders every pass with one camera, composites them and writes the timing table."""
    out = check_out_dir("--out", args.out)
    check_image(args.size, 4 * PIXEL_BYTES)  # several passes + the composite
    if args.frames > MAX_FRAMES:
        raise CliError(f"--frames must be at most {MAX_FRAMES}, got {args.frames}")
    w, h = args.size
    check_memory("--frames", str(args.frames), float(args.frames) * w * h * 3)
    from jaxgfx.showcase import data_source

    try:
        data, source = data_source(args.data)
    except ValueError as err:
        raise CliError(f"--data: {err}") from None
    import imageio.v3 as iio
    import jax
    import numpy as np

    from jaxgfx._src.report import machine, markdown_table, time_jitted
    from jaxgfx.compose import Frame, coverage, depth_image, to_uint8
    from jaxgfx.io import atomic_write, save_json, save_png
    from jaxgfx.showcase import build_demo

    demo = build_demo(w, h, key=jax.random.key(args.seed), data=data)
    rows, frames, names = [], [], []
    for name, fn, fn_args, first in demo.passes:
        c, t, result = time_jitted(fn, *fn_args)
        c = c if first is None else first
        if isinstance(result, Frame):  # other stages (terrain generation) feed a pass
            frames.append(result)
            names.append(name)
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
    share = [float(x) for x in np.asarray(coverage(frames))]
    cover = [dict(stage=n, share=f"{100 * x:.1f} %") for n, x in zip(names, share)]
    with writing("--out", out):
        save_png(out / "color.png", frame.color)
        save_png(out / "depth.png", depth_image(frame.depth))
    wrote = [out / "color.png", out / "depth.png"]
    if args.frames:
        # The character walks; the other passes' frames stay as they are.
        still = frames[:-1]
        gif = [
            to_uint8(demo.composite(still + [demo.animate(demo.camera, k / args.frames)]).color)
            for k in range(args.frames)
        ]
        with writing("--out", out), atomic_write(out / "demo.gif") as tmp:
            iio.imwrite(
                tmp, np.stack([np.asarray(g) for g in gif]), extension=".gif", duration=110, loop=0
            )
        wrote.append(out / "demo.gif")
    for r in rows:
        r["compile_s"] = f"{r['compile_s']:.2f}"
        r["ms"] = f"{r['ms']:.1f}"
    mach = machine()
    md = (
        f"# jaxgfx demo {w}x{h}\n\n{source}\n\n{demo.description}\n\n"
        + "".join(f"{c}.\n" for c in demo.credits)
        + f"\nmachine: {mach}\n\n"
        "compile_s: first call (trace + compile + run); ms: median of 3 later calls\n\n"
        + markdown_table(rows, ["stage", "compile_s", "ms"])
        + "\n\nShare of the frame each pass shows after depth compositing:\n\n"
        + markdown_table(cover, ["stage", "share"])
        + "\n"
    )
    with writing("--out", out):
        with atomic_write(out / "timing.md") as tmp:
            tmp.write_text(md)
        save_json(
            out / "timing.json",
            dict(
                size=[w, h],
                data=source,
                scene=demo.description,
                credits=list(demo.credits),
                machine=mach,
                stages=rows,
                coverage=dict(zip(names, share)),
            ),
        )
    print(md)  # with the data credits, once
    print("wrote " + ", ".join(str(p) for p in wrote + [out / "timing.md"]))
    return 0
