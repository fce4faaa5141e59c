"""Clip-Box height-map renders against a full-resolution heightfield mesh (issue 17).

For each real height map and view, ``jaxgfx terrain`` renders the Clip-Box terrain with
``--depth`` and prints its mapping; the reference is the same samples as a heightfield
triangle mesh built with NumPy from the PRINTED mapping (sample (r, c) at
x = origin_x + (c + 0.5) cell, z = origin_z + (r + 0.5) cell, y = base + (v - min)
vertical_scale), drawn by ``rasterize`` with the same camera.  The terrain function
goes on past the map (``"edge": "clamp"``: the edge samples extend outwards), so the
reference does too, as far as the outer Clip-Box reaches (its footprint follows from
the viewer, N and L alone); the renderer shows nothing beyond that box.

Reported per view: among pixels where the reference is hit, the fraction whose Clip-Box
depth is within 3 % (or 1 voxel) of it; the terrain/sky mask agreement; and the signed
depth difference by depth band (negative: the Clip-Box surface is nearer, i.e. higher).
Each view also writes ``*_diff.png`` (see :func:`difference_image`).

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
from jaxgfx.io import save_png
from jaxgfx.raster import rasterize

MAPS = ("SainteHelens.dem", "gcanyon_elev_crop.bw.png")
VIEWS = {
    "default": [],
    "above": ["--viewer", "0,420,0", "--camera", "180,-89", "--fog", "0"],
    "low": ["--viewer", "-60,{low},120", "--camera", "160,-5"],
    "oblique": ["--viewer", "100,{high},200", "--camera", "210,-35"],
}
BANDS = ((0, 32), (32, 64), (64, 128), (128, 256), (256, 1e9))
FOV = 60.0
DEPTH_TARGET, MASK_TARGET = 0.95, 0.97  # issue 17's acceptance


def surface(heights: np.ndarray, mapping: dict, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """World y of the printed mapping's surface on the grid ``x`` (W,) by ``z`` (H,).

    Bilinear between sample centres, the edge samples extended outwards (``"edge":
    "clamp"``): separable ``np.interp``, which clamps at the ends -- NumPy only, no
    jaxgfx code.  At sample centres it returns the samples exactly.
    """
    if mapping.get("edge", "clamp") != "clamp":
        raise SystemExit(f"the reference builds clamped maps only, got edge {mapping['edge']!r}")
    rows, cols = heights.shape
    ox, oz = mapping["origin"]
    xs = ox + (np.arange(cols) + 0.5) * mapping["cell"]
    zs = oz + (np.arange(rows) + 0.5) * mapping["cell"]
    rel = (heights - heights.min()) * mapping["vertical_scale"]
    along_x = np.stack([np.interp(x, xs, row) for row in rel])  # (rows, W)
    grid = np.stack([np.interp(z, zs, col) for col in along_x.T], axis=1)  # (H, W)
    return mapping["base"] + grid


def heightfield_mesh(
    heights: np.ndarray, mapping: dict, extent: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices and (F, 3) triangles of the full-resolution map over ``extent``.

    One vertex per sample centre inside ``extent = (x0, x1, z0, z1)`` plus the extent's
    border lines, so beyond the map the clamped skirt (planar between the border and
    the edge samples) reaches the border, and a map larger than the extent is cut there.
    """
    rows, cols = heights.shape
    x0, x1, z0, z1 = extent
    xs = mapping["origin"][0] + (np.arange(cols) + 0.5) * mapping["cell"]
    zs = mapping["origin"][1] + (np.arange(rows) + 0.5) * mapping["cell"]
    x = np.unique(np.concatenate([[x0, x1], xs[(xs > x0) & (xs < x1)]]))
    z = np.unique(np.concatenate([[z0, z1], zs[(zs > z0) & (zs < z1)]]))
    y = surface(heights, mapping, x, z)
    n = x.size
    zz, xx = np.meshgrid(z, x, indexing="ij")
    idx = (np.arange(z.size)[:, None] * n + np.arange(n))[:-1, :-1].ravel()
    faces = np.concatenate(
        [
            np.stack([idx, idx + 1, idx + n], -1),
            np.stack([idx + 1, idx + n + 1, idx + n], -1),
        ]
    )
    return np.stack([xx, y, zz], -1).reshape(-1, 3), faces.astype(np.int32)


def clipbox_extent(viewer, resolution: int, levels: int) -> tuple[float, float, float, float]:
    """(x0, x1, z0, z1) world footprint of the outer Clip-Box around ``viewer``.

    The outer level's voxel ``i`` (edge ``s = 2^(L-1)``) is the cube centred on its
    sample's cell, ``origin + i s + 1/2 +- s/2``; its surface reaches no further.
    """
    lvl = levels - 1
    s = 1 << lvl
    o = T.clipbox_origin(np.asarray(viewer, np.int64), lvl, resolution)
    lo = o + 0.5 - s / 2
    hi = lo + resolution * s
    return float(lo[0]), float(hi[0]), float(lo[2]), float(hi[2])


def difference_image(ref: np.ndarray, got: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(H, W, 3) picture of the disagreement: grey = within tolerance (darker = farther),
    red = Clip-Box nearer than the reference (higher ground), blue = farther (lower),
    yellow = Clip-Box terrain where the reference is sky, magenta = the reverse, black = sky."""
    hit, drawn = np.isfinite(ref), np.isfinite(got)
    img = np.zeros(ref.shape + (3,), np.float32)
    both = hit & drawn
    far = np.nanmax(np.where(hit, ref, np.nan)) if hit.any() else 1.0
    grey = 0.85 - 0.6 * np.where(hit, ref, 0.0) / max(far, 1e-6)
    img[ok] = grey[ok, None]
    near = both & ~ok & (got < np.where(hit, ref, 0.0))
    img[near] = (1.0, 0.15, 0.1)
    img[both & ~ok & ~near] = (0.15, 0.35, 1.0)
    img[drawn & ~hit] = (1.0, 0.9, 0.1)
    img[hit & ~drawn] = (0.9, 0.1, 0.9)
    return img


def run_view(path, view, extra, size, out_dir, resolution=64, levels=5, options=()):
    """One CLI render + its reference; returns the row of numbers."""
    tag = f"{path.stem.split('.')[0]}_{view}"
    png, npy = out_dir / f"{tag}.png", out_dir / f"{tag}_depth.npy"
    argv = ["terrain", "--function", f"heightmap:{path}", "--size", f"{size[0]}x{size[1]}"]
    argv += ["--out", str(png), "--depth", str(npy), *extra]
    argv += ["--resolution", str(resolution), "--levels", str(levels), *options]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        if cli_main(argv) != 0:
            raise SystemExit(f"jaxgfx {' '.join(argv)} failed")
    rep = json.loads(buf.getvalue().strip().splitlines()[-1])
    heights = T.read_heightmap(path).heights
    extent = clipbox_extent(rep["viewer"], resolution, levels)
    verts, faces = heightfield_mesh(heights, rep, extent)
    verts = verts - np.asarray(rep["viewer"], np.float64)  # viewer-relative, like the CLI
    reach = resolution * (1 << (levels - 1)) // 2
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
    save_png(out_dir / f"{tag}_diff.png", difference_image(ref, got, ok))
    row = dict(
        map=path.name,
        view=view,
        viewer=str(tuple(rep["viewer"])),
        camera=str(tuple(rep["camera"])),
        reference_hit=float(hit.mean()),
        depth_ok=float(ok.sum() / max(hit.sum(), 1)),
        masks_agree=float(np.mean(hit == drawn)),
    )
    row["meets"] = row["depth_ok"] >= DEPTH_TARGET and row["masks_agree"] >= MASK_TARGET
    for lo, hi in BANDS:
        m = both & (ref >= lo) & (ref < hi)
        row[f"median_diff_{lo}"] = float(np.median(diff[m])) if m.any() else None
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/heightmap_reference", help="output folder")
    p.add_argument("--size", default="320x240", help="WxH of every render")
    p.add_argument("--resolution", type=int, default=64, help="Clip-Box N (CLI default 64)")
    p.add_argument("--levels", type=int, default=5, help="Clip-Box levels (CLI default 5)")
    p.add_argument("--options", default="", help="more `jaxgfx terrain` options for every render")
    p.add_argument("--maps", default="", help="comma-separated subset of the maps' stems")
    p.add_argument("--quick", action="store_true", help="one map, two views, 160x120")
    args = p.parse_args(argv)
    size = (160, 120) if args.quick else tuple(int(v) for v in args.size.lower().split("x"))
    maps = MAPS[:1] if args.quick else MAPS
    if args.maps:
        maps = tuple(m for m in maps if m.split(".")[0] in args.maps.split(","))
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
            rows.append(
                run_view(
                    path,
                    view,
                    extra,
                    size,
                    out_dir,
                    args.resolution,
                    args.levels,
                    args.options.split(),
                )
            )
            print(json.dumps(rows[-1]))
    cols = ["map", "view", "viewer", "camera", "reference_hit", "depth_ok", "masks_agree", "meets"]
    cols += [f"median_diff_{lo}" for lo, _ in BANDS]
    md = markdown_table(rows, cols) + f"\n\n{machine()}\n"
    met = sum(r["meets"] for r in rows)
    md += (
        f"\n{met} of {len(rows)} views meet depth >= {DEPTH_TARGET} and masks >= "
        f"{MASK_TARGET} (N = {args.resolution}, L = {args.levels}, {size[0]}x{size[1]}).\n"
    )
    title = "Clip-Box height maps against a full-resolution heightfield"
    write_table(out_dir, title, md, {"rows": rows, "machine": machine()})
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
