"""Clip-Box height-map renders against a full-resolution heightfield mesh (issue 17).

For each real height map and view, ``jaxgfx terrain`` renders the Clip-Box terrain with
``--depth`` and prints its mapping; the reference is the same samples as a heightfield
triangle mesh built with NumPy from the PRINTED mapping (sample (r, c) at
x = origin_x + (c + 0.5) cell, z = origin_z + (r + 0.5) cell, y = base + (v - min)
vertical_scale), drawn by ``rasterize`` with the same camera.  Reported: among pixels
where the reference is hit, the fraction whose Clip-Box depth is within 3 % (or 1 voxel)
of it; the terrain/sky mask agreement; and the signed depth difference by depth band
(negative: the Clip-Box surface is nearer, i.e. higher).  The reference ends at the map's
edge while the Clip-Box terrain goes on (clamped edges), so views that see past the edge
lose mask agreement there.

    python -m experiments.heightmap_reference --out out/hr [--size 320x240] [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from experiments.common import DATA, machine, markdown_table, write_table
from jaxgfx import terrain as T
from jaxgfx.camera import camera_from_degrees
from jaxgfx.cli import main as cli_main
from jaxgfx.raster import rasterize

MAPS = ("SainteHelens.dem", "gcanyon_elev_crop.bw.png")
VIEWS = {
    "default": [],
    "above": ["--viewer", "0,420,0", "--camera", "180,-89", "--fog", "0"],
    "low": ["--viewer", "-60,{low},120", "--camera", "160,-5"],
    "oblique": ["--viewer", "100,{high},200", "--camera", "210,-35"],
}
BANDS = ((0, 32), (32, 64), (64, 128), (128, 256), (256, 1e9))
RESOLUTION, LEVELS, FOV = 64, 5, 60.0


def heightfield_mesh(heights: np.ndarray, mapping: dict) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 sample positions and (F, 3) triangles of the full-resolution map."""
    rows, cols = heights.shape
    r, c = np.mgrid[0:rows, 0:cols]
    ox, oz = mapping["origin"]
    x = ox + (c + 0.5) * mapping["cell"]
    z = oz + (r + 0.5) * mapping["cell"]
    y = mapping["base"] + (heights - heights.min()) * mapping["vertical_scale"]
    idx = (r * cols + c)[:-1, :-1].ravel()
    faces = np.concatenate(
        [
            np.stack([idx, idx + 1, idx + cols], -1),
            np.stack([idx + 1, idx + cols + 1, idx + cols], -1),
        ]
    )
    return np.stack([x, y, z], -1).reshape(-1, 3), faces.astype(np.int32)


def run_view(path, view, extra, size, out_dir):
    """One CLI render + its reference; returns the row of numbers."""
    tag = f"{path.stem.split('.')[0]}_{view}"
    png, npy = out_dir / f"{tag}.png", out_dir / f"{tag}_depth.npy"
    argv = ["terrain", "--function", f"heightmap:{path}", "--size", f"{size[0]}x{size[1]}"]
    argv += ["--out", str(png), "--depth", str(npy), *extra]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        if cli_main(argv) != 0:
            raise SystemExit(f"jaxgfx {' '.join(argv)} failed")
    rep = json.loads(buf.getvalue().strip().splitlines()[-1])
    heights = T.read_heightmap(path).heights
    verts, faces = heightfield_mesh(heights, rep)
    verts = verts - np.asarray(rep["viewer"], np.float64)  # viewer-relative, like the CLI
    reach = RESOLUTION * (1 << (LEVELS - 1)) // 2
    yaw, pitch = rep["camera"]
    cam = camera_from_degrees((0.0, 0.0, 0.0), yaw, pitch, 0.0, FOV, *size, 0.25, 8.0 * reach)
    ref = np.asarray(
        jax.jit(rasterize)(cam, jnp.asarray(verts, jnp.float32), jnp.asarray(faces)).depth
    )
    got = np.load(npy)
    hit, drawn = np.isfinite(ref), np.isfinite(got)
    both = hit & drawn
    diff = np.where(both, got - np.where(hit, ref, 0.0), np.nan)
    ok = both & (np.abs(np.nan_to_num(diff, nan=np.inf)) <= np.maximum(0.03 * ref, 1.0))
    row = dict(
        map=path.name,
        view=view,
        viewer=str(tuple(rep["viewer"])),
        camera=str(tuple(rep["camera"])),
        reference_hit=float(hit.mean()),
        depth_ok=float(ok.sum() / max(hit.sum(), 1)),
        masks_agree=float(np.mean(hit == drawn)),
    )
    for lo, hi in BANDS:
        m = both & (ref >= lo) & (ref < hi)
        row[f"median_diff_{lo}"] = float(np.median(diff[m])) if m.any() else None
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/heightmap_reference", help="output folder")
    p.add_argument("--size", default="320x240", help="WxH of every render")
    p.add_argument("--quick", action="store_true", help="one map, two views, 160x120")
    args = p.parse_args(argv)
    size = (160, 120) if args.quick else tuple(int(v) for v in args.size.lower().split("x"))
    maps = MAPS[:1] if args.quick else MAPS
    views = {k: VIEWS[k] for k in ("default", "low")} if args.quick else VIEWS
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in maps:
        path = DATA / "terrain" / name
        if not path.exists():
            print(f"skipping {name}: {path} is absent (../shared/data)", file=sys.stderr)
            continue
        t = T.heightmap_terrain(path)
        top = int(np.max(np.asarray(t.heights)) + t.mapping.base)
        for view, extra in views.items():
            extra = [e.format(low=top // 2 + 40, high=top + 60) for e in extra]
            rows.append(run_view(path, view, extra, size, out_dir))
            print(json.dumps(rows[-1]))
    cols = ["map", "view", "viewer", "camera", "reference_hit", "depth_ok", "masks_agree"]
    cols += [f"median_diff_{lo}" for lo, _ in BANDS]
    md = markdown_table(rows, cols) + f"\n\n{machine()}\n"
    title = "Clip-Box height maps against a full-resolution heightfield"
    write_table(out_dir, title, md, {"rows": rows, "machine": machine()})
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
