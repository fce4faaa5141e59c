"""What ``jaxgfx sweep`` writes to disk, and a Ctrl-C in the middle of it.

Runs the ``jaxgfx sweep`` command (a fresh process, as a user would) over the bunny
(``meshes/bun_zipper_res2.ply`` of the shared data; a torus without it) and counts the bytes
of every part of its output folder: the frames (PNG), the chunks (compressed depth), the
contact sheet.  ``raw_MB`` is what the same frames take as uncompressed 8-bit colour plus
float32 depth, 7 bytes a pixel.  Then the same sweep is started into a new folder, sent
SIGINT (Ctrl-C) when a third of its chunks are on disk, and started again: the table's
second row gives the exit code and the last line of the interrupted run, the frames kept,
and what the resumed run computed and skipped; its bytes equal the uninterrupted run's.

Usage::

    python -m experiments.sweep_storage --out out/sweep_storage            # 1000 x 320x240
    python -m experiments.sweep_storage --quick --out out/sweep_storage    # 12 x 96x72
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from experiments.common import DATA
from jaxgfx._src.report import machine, markdown_table, write_table


def _mesh(tmp: Path) -> tuple[str, str]:
    bunny = DATA / "meshes" / "bun_zipper_res2.ply"
    if bunny.is_file():
        return str(bunny), "bunny (bun_zipper_res2.ply)"
    import trimesh

    path = tmp / "torus.ply"
    trimesh.creation.torus(1.0, 0.35).export(path)
    return str(path), "torus (no shared data)"


def _sizes(out: Path) -> dict:
    def mb(paths) -> float:
        return sum(p.stat().st_size for p in paths) / 1e6

    files = [p for p in out.rglob("*") if p.is_file()]
    return dict(
        total_MB=mb(files),
        frames_MB=mb(out.glob("frame_*.png")),
        chunks_MB=mb((out / "chunks").glob("chunk_*.npz")),
        sheet_MB=mb([out / "contact_sheet.png"]),
    )


def _command(mesh: str, n: int, size: str, chunk: int, out: Path) -> list[str]:
    return [sys.executable, "-m", "jaxgfx.cli", "sweep", mesh, "--n", str(n), "--size", size,
            "--chunk", str(chunk), "--out", str(out)]  # fmt: skip


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="12 frames at 96x72")
    p.add_argument("--out", default="out/sweep_storage", help="folder for the table")
    args = p.parse_args(argv)
    n, size, chunk = (12, "96x72", 4) if args.quick else (1000, "320x240", 8)
    w, h = (int(v) for v in size.split("x"))
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="sweep-storage-"))
    rows = []
    try:
        mesh, what = _mesh(tmp)
        full = tmp / "full"
        t0 = time.perf_counter()
        done = subprocess.run(_command(mesh, n, size, chunk, full), capture_output=True, text=True)
        seconds = time.perf_counter() - t0
        if done.returncode != 0:
            raise SystemExit(done.stderr[-3000:])
        sizes = _sizes(full)
        rows.append(
            dict(
                run="uninterrupted",
                mesh=what,
                frames=n,
                size=size,
                **{k: round(v, 2) for k, v in sizes.items()},
                raw_MB=round(n * w * h * 7 / 1e6, 1),
                bytes_per_pixel=round(sizes["total_MB"] * 1e6 / (n * w * h), 3),
                seconds=round(seconds, 1),
                note="",
            )
        )
        # The same sweep, Ctrl-C once a third of the chunks are written, then started again.
        part = tmp / "interrupted"
        # Ctrl-C reaches the sweep even where this script runs with SIGINT ignored (a
        # background job of a non-interactive shell), which its children would inherit.
        proc = subprocess.Popen(
            _command(mesh, n, size, chunk, part), stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
            text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )  # fmt: skip
        chunks = -(-n // chunk)
        while proc.poll() is None and len(list(part.glob("chunks/chunk_*.npz"))) < chunks // 3:
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGINT)
        _, err = proc.communicate()
        last = err.replace("\r", "\n").strip().splitlines()[-1]
        again = subprocess.run(_command(mesh, n, size, chunk, part), capture_output=True, text=True)
        summary = json.loads(again.stdout.strip().splitlines()[-1])
        same = _sizes(part)["total_MB"] == sizes["total_MB"]
        rows.append(
            dict(
                run=f"Ctrl-C, exit {proc.returncode}; resumed: computed {summary['computed']}, "
                f"skipped {summary['skipped']} chunks",
                mesh=what,
                frames=n,
                size=size,
                **{k: round(v, 2) for k, v in _sizes(part).items()},
                raw_MB=round(n * w * h * 7 / 1e6, 1),
                bytes_per_pixel=round(_sizes(part)["total_MB"] * 1e6 / (n * w * h), 3),
                seconds="",
                note=f"{last!r}; same bytes as uninterrupted: {same}",
            )
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    cols = ["run", "mesh", "frames", "size", "total_MB", "frames_MB", "chunks_MB", "sheet_MB",
            "raw_MB", "bytes_per_pixel", "seconds", "note"]  # fmt: skip
    title = f"jaxgfx sweep storage, {n} frames at {size}"
    table = f"machine: {machine()}\n\n" + markdown_table(rows, cols)
    print(f"# {title}\n\n{table}")
    write_table(out_dir, title, table, dict(machine=machine(), rows=rows), stem="sweep_storage")


if __name__ == "__main__":
    main()
