"""The benchmarks page: runs the peer benchmarks and collects their tables into one Markdown page.

Each benchmark below is an experiment of its own (``python -m experiments.NAME``); this runs them
one after another as subprocesses, each with ``--out DIR/NAME`` (and ``--quick`` when given;
what it prints is kept beside its tables as ``DIR/NAME/stdout.txt``), and joins the Markdown
tables they write into one page: a header with the machine and the date, then every table under
the command that reproduces it.  The page is ``benchmarks.md`` (with ``benchmarks.json``: the
machine, the date, each command, its wall time and its own JSON table) in ``--out``, and/or
``docs/benchmarks.md`` with ``--docs`` (the docs site's benchmarks page).

A full run takes tens of minutes on a 2-core machine and needs the peers of
``pip install ".[bench]"`` (each benchmark skips a missing peer and prints why).  ``--quick``
passes ``--quick`` on and, unless ``--only`` names others, runs only the fastest benchmark
(``QUICK_DEFAULT``) so that it takes well under a minute: a smoke test of the page, not
numbers to quote.  ``--docs`` needs the full run (neither ``--quick`` nor ``--only``).  Any
failed benchmark fails the report, and no page is written.

Usage::

    python -m experiments.report --docs                 # regenerate docs/benchmarks.md
    python -m experiments.report --quick --out out/report
    python -m experiments.report --only bench_raster,rle_bench --out out/report
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import NamedTuple

from experiments.common import machine, write_table
from jaxgfx.io import atomic_write

ROOT = Path(__file__).resolve().parents[1]
DOCS_PAGE = ROOT / "docs" / "benchmarks.md"


class Benchmark(NamedTuple):
    name: str  # the module under experiments/
    title: str  # the page's heading for its tables
    args: tuple[str, ...]  # extra arguments of the full run
    about: str  # one paragraph: what is compared, how to read the ratios


BENCHMARKS = (
    Benchmark(
        "bench_raster",
        "Rasterizer against CPU renderers",
        (),
        "`jax.jit(rasterize)` (colour, depth and face ids) against open3d's `RaycastingScene` "
        "(Embree, every core), Mesa llvmpipe (OpenGL, depth read back) and trimesh on embreex, "
        "same mesh, cameras and size; then batches of cameras, frames per second.",
    ),
    Benchmark(
        "rle_bench",
        "Ray caster against Embree and the per-pixel DDA",
        # The 1024^3 memory table (Table 4.1 at the thesis resolution) is not a peer comparison
        # and voxelizing at that size takes minutes: `python -m experiments.rle_bench` has it.
        ("--bits-res", "0"),
        "The per-plane RLE ray caster (512x384, 2x1 anti-aliasing) against Embree (open3d) on "
        "the same voxels' exposed cube faces, the per-pixel 3-D DDA, splatting and the meshes' "
        "own triangles; batched cameras; instance counts (Fig. 4.23 / 4.30).",
    ),
    Benchmark(
        "skinning_bench",
        "Skinning against numba",
        (),
        "About a million vertices of posed limbs (thesis Table 5.2 / 5.3): LBS, DQS and spline "
        "skinning with and without deformation styles, against LBS in numba `prange` on every "
        "core and a memory-copy bound.",
    ),
    Benchmark(
        "fit_bench",
        "Image-fitting cost against Mitsuba 3",
        (),
        "A coverage frame, its analytic antialiasing and the gradients of an image loss through "
        "both (vertices, camera), the rasterizer's own reverse, a whole style-fit step; beside "
        "Mitsuba 3's projective-sampling gradients of the same loss (skipped without an LLVM >= "
        "16).",
    ),
    Benchmark(
        "clipbox_table",
        "Clip-Box terrain and meshing against VTK",
        (),
        "Thesis Table 3.1 (50,000 CSG operations, 7 levels, a fly path), and `voxels_to_mesh` "
        "against VTK's FlyingEdges3D (one thread) and scikit-image's marching cubes on the same "
        "boxes.",
    ),
    Benchmark(
        "sweep_scaling",
        "Sweeps over every core",
        (),
        "One sharded batch of frames on one core (the process pinned), then on every core with "
        "one host device per core; frames/s, speed-up, CPU time per wall second.",
    ),
)
BY_NAME = {b.name: b for b in BENCHMARKS}
QUICK_DEFAULT = ("sweep_scaling",)  # the fastest; --quick runs only it unless --only says


def command(bench: Benchmark, quick: bool) -> list[str]:
    """The command line that reproduces ``bench``'s tables (``--out DIR`` left to the caller)."""
    return ["python", "-m", f"experiments.{bench.name}", *bench.args, *(["--quick"] * quick)]


def _shell(cmd: list[str]) -> str:
    return " ".join(cmd + ["--out", "DIR"])


def demote(markdown: str) -> str:
    """A benchmark's table page as a section of this page.

    Its ``# title`` line goes (the section has its own heading) and its other headings
    become level 3, under the section's level 2.
    """
    text = re.sub(r"\A# [^\n]*\n+", "", markdown.strip())
    return re.sub(r"^#{1,2} ", "### ", text, flags=re.MULTILINE)


def run_one(bench: Benchmark, quick: bool, out: Path) -> dict:
    """Runs one benchmark into ``out``; returns its command, wall time, exit code, table, data."""
    cmd = command(bench, quick)
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, *cmd[1:], "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    seconds = time.perf_counter() - t0
    # What the benchmark printed (skipped peers, progress, its tables): the smoke test of a
    # benchmark that `--quick` runs reads it here instead of running the benchmark again.
    with atomic_write(out / "stdout.txt") as tmp:
        tmp.write_text(res.stdout)
    md = out / "table.md"
    js = out / "table.json"
    return {
        "name": bench.name,
        "command": _shell(cmd),
        "seconds": round(seconds, 1),
        "returncode": res.returncode,
        "stderr_tail": res.stderr[-3000:] if res.returncode else "",
        "markdown": md.read_text() if md.exists() else "",
        "data": json.loads(js.read_text()) if js.exists() else None,
    }


def page(results: list[dict], *, quick: bool, when: str, host: str) -> str:
    """The page's body (below its ``# Benchmarks`` title)."""
    lines = [
        f"Generated on {when} by `python -m experiments.report"
        + (" --quick" if quick else "")
        + "`, which runs each benchmark below and collects its tables.",
        "",
        f"Machine: {host}.",
        "",
        "Ratios are measured in the same run, on the same machine, with the same inputs; times "
        "are steady state (compilation is reported apart). Peers come with "
        '`pip install ".[bench]"`; a missing peer is skipped and named under its table.',
    ]
    if quick:
        lines += [
            "",
            "Quick mode: small inputs and few repeats, a smoke test of this page; these are not "
            "numbers to quote.",
        ]
    for r in results:
        bench = BY_NAME[r["name"]]
        lines += ["", f"## {bench.title}", "", bench.about, ""]
        lines += [f"Reproduce: `{r['command']}` ({r['seconds']:.0f} s here).", ""]
        lines.append(demote(r["markdown"]))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="Benchmarks: " + ", ".join(BY_NAME) + ".",
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="pass --quick to each benchmark and run only "
        + ", ".join(QUICK_DEFAULT)
        + " unless --only names others (under a minute)",
    )
    ap.add_argument(
        "--out",
        default=None,
        help="write benchmarks.md / benchmarks.json here, each benchmark's own files and "
        "printed output (stdout.txt) in a subfolder named after it",
    )
    ap.add_argument(
        "--docs",
        action="store_true",
        help="write the page to docs/benchmarks.md (a full run: not with --quick or --only)",
    )
    ap.add_argument("--only", default=None, help="comma-separated benchmarks to run (default all)")
    args = ap.parse_args(argv)
    if args.docs and (args.quick or args.only):
        ap.error(
            "--docs writes the docs page from a full run of every benchmark: drop --quick/--only"
        )
    if args.only:
        names = [n.strip() for n in args.only.split(",") if n.strip()]
        unknown = [n for n in names if n not in BY_NAME]
        if unknown:
            ap.error(
                f"--only: unknown benchmark(s) {', '.join(unknown)}; one of {', '.join(BY_NAME)}"
            )
    else:
        names = list(QUICK_DEFAULT if args.quick else BY_NAME)
    selected = [BY_NAME[n] for n in names]

    host = machine()
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    with tempfile.TemporaryDirectory(prefix="jaxgfx-report-") as tmp:
        base = Path(args.out) if args.out else Path(tmp)
        results = []
        for bench in selected:
            print(f"running {_shell(command(bench, args.quick))}", flush=True)
            r = run_one(bench, args.quick, base / bench.name)
            print(f"  {bench.name}: exit {r['returncode']} after {r['seconds']:.0f} s", flush=True)
            results.append(r)
    failed = [r for r in results if r["returncode"] or not r["markdown"]]
    for r in failed:
        print(f"{r['name']} failed (exit {r['returncode']}):\n{r['stderr_tail']}", file=sys.stderr)
    if failed:
        return 1

    body = page(results, quick=args.quick, when=when, host=host)
    print(body)
    data = {
        "machine": host,
        "generated": when,
        "quick": args.quick,
        "benchmarks": [{k: r[k] for k in ("name", "command", "seconds", "data")} for r in results],
    }
    if args.out:
        write_table(args.out, "Benchmarks", body, data, stem="benchmarks")
    if args.docs:
        with atomic_write(DOCS_PAGE) as tmp:
            tmp.write_text(f"# Benchmarks\n\n{body}\n")
        print(f"wrote {DOCS_PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
