"""Clip-Box height-map renders against a full-resolution heightfield mesh.

For each height map and view, ``jaxgfx terrain`` renders the Clip-Box terrain with
``--depth`` and prints its mapping; the reference is the same samples as a heightfield
triangle mesh built with NumPy from the PRINTED mapping (sample (r, c) at
x = origin_x + (c + 0.5) cell[0], z = origin_z + (r + 0.5) cell[1], y = base + (v - min)
vertical_scale), drawn by ``rasterize`` with the same camera.  Beyond the map the
printed ``apron`` says what the terrain does (``"edge": "apron"``: the edge samples
extend outwards and fade, by the smoothstep of the Euclidean distance beyond the map
over ``fade`` voxels, to the flat level ``y``), so the reference does too, as far as
the outer Clip-Box reaches (its footprint follows from the viewer, N and L alone).

The maps: the St Helens USGS DEM and the Grand Canyon image from ``../shared/data``,
and elevation files made from them with known georeferencing (:func:`make_inputs`):
a geographic GeoTIFF (EPSG:4326, int16, 1 x 1.4 arc-seconds, voids), a UTM GeoTIFF
(EPSG:32610, float32, 30 m), an SRTM ``.hgt`` tile (3 arc-seconds), an ESRI ASCII grid
(30 m, NODATA voids) and a 16-bit PNG (a 480 x 364 crop of the canyon).  For each the
table gives the printed ``metres_per_sample`` against the truth (the distance between neighbouring
samples' Earth-centred WGS 84 positions, computed here) and ``metres_per_voxel``.

Reported per view: among pixels where the reference is hit, the fraction whose Clip-Box
depth is within 3 % (or 1 voxel) of it; the terrain/sky mask agreement; and the signed
depth difference by depth band (negative: the Clip-Box surface is nearer, i.e. higher).
Besides the four views over the map, ``--edges`` adds eight from beyond the map's
edges: from outside each edge looking back at the map, and from inside it looking out.
Each view also writes ``*_diff.png`` (see :func:`difference_image`).

    python -m experiments.heightmap_reference --out out/hr [--size 320x240] [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
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

VIEWS = {
    "default": [],
    "above": ["--viewer", "0,{above},0", "--camera", "180,-89", "--fog", "0"],
    "low": ["--viewer", "-60,{low},120", "--camera", "160,-5"],
    "oblique": ["--viewer", "100,{high},200", "--camera", "210,-35"],
}
EDGES = ("west", "east", "north", "south")
BANDS = ((0, 32), (32, 64), (64, 128), (128, 256), (256, 1e9))
FOV = 60.0
DEPTH_TARGET, MASK_TARGET = 0.95, 0.97  # the acceptance thresholds


def _ecef(lat_deg: float, lon_deg: float) -> np.ndarray:
    a, e2 = 6378137.0, 6.69437999014e-3
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    n = a / math.sqrt(1 - e2 * math.sin(lat) ** 2)
    return np.array(
        [
            n * math.cos(lat) * math.cos(lon),
            n * math.cos(lat) * math.sin(lon),
            n * (1 - e2) * math.sin(lat),
        ]
    )


def ground_spacing(lat: float, lon: float, dlon: float, dlat: float) -> tuple[float, float]:
    """(east-west, north-south) metres between neighbouring samples at (lat, lon): the
    chord between their Earth-centred WGS 84 positions (independent of jaxgfx)."""
    p = _ecef(lat, lon)
    return (
        float(np.linalg.norm(_ecef(lat, lon + dlon) - p)),
        float(np.linalg.norm(_ecef(lat + dlat, lon) - p)),
    )


def _geotiff(
    path: Path, arr: np.ndarray, *, geographic: bool, scale, tie, code: int, nodata=None
) -> None:
    import tifffile

    keys = [(1024, 0, 1, 2 if geographic else 1), (1025, 0, 1, 1)]
    keys.append((2048, 0, 1, code) if geographic else (3072, 0, 1, code))
    if not geographic:
        keys.append((3076, 0, 1, 9001))
    directory = [1, 1, 0, len(keys)] + [v for k in keys for v in k]
    tags = [
        (34735, "H", len(directory), directory, False),
        (33550, "d", 3, (scale[0], scale[1], 0.0), False),
        (33922, "d", 6, (0.0, 0.0, 0.0, tie[0], tie[1], 0.0), False),
    ]
    if nodata is not None:
        tags.append((42113, "s", 0, str(nodata), False))
    tifffile.imwrite(path, arr, extratags=tags, compression="zlib", predictor=True)


def make_inputs(out: Path) -> dict[str, tuple[Path, tuple[float, float] | None]]:
    """Elevation files with known georeferencing made from the real maps; returns
    ``{name: (path, true metres per sample (x, z) or None)}``."""
    out.mkdir(parents=True, exist_ok=True)
    sh_path = DATA / "terrain" / "SainteHelens.dem"
    gc_path = DATA / "terrain" / "gcanyon_elev_crop.bw.png"
    files: dict[str, tuple[Path, tuple[float, float] | None]] = {}
    if sh_path.exists():
        sh = T.read_heightmap(sh_path).heights  # 466 x 327 metres on a 30 m UTM grid
        voids = np.zeros(sh.shape, bool)
        voids[200:206, 100:104] = voids[40:42, 250:255] = True
        # EPSG:4326, 1 arc-second north-south by 1.4 east-west (~30 m each at 46.2 N)
        lat0, lon0 = 46.27, -122.25
        geo = np.where(voids, -32768, np.round(sh)).astype(np.int16)
        p = out / "sthelens_4326.tif"
        _geotiff(
            p,
            geo,
            geographic=True,
            scale=(1.4 / 3600, 1 / 3600),
            tie=(lon0, lat0),
            code=4326,
            nodata=-32768,
        )
        lat_c = lat0 - sh.shape[0] / 2 / 3600
        files["sthelens_4326.tif"] = (p, ground_spacing(lat_c, lon0, 1.4 / 3600, 1 / 3600))
        p = out / "sthelens_utm.tif"
        _geotiff(
            p,
            sh.astype(np.float32),
            geographic=False,
            scale=(30.0, 30.0),
            tie=(557000.0, 5120000.0),
            code=32610,
        )
        files["sthelens_utm.tif"] = (p, (30.0, 30.0))
        p = out / "sthelens.asc"
        rows = np.where(voids, -9999.0, sh)
        with open(p, "w") as fh:
            fh.write(
                f"ncols {sh.shape[1]}\nnrows {sh.shape[0]}\nxllcorner 557000\n"
                "yllcorner 5106020\ncellsize 30\nNODATA_value -9999\n"
            )
            np.savetxt(fh, rows, fmt="%.1f")
        files["sthelens.asc"] = (p, (30.0, 30.0))
    if gc_path.exists():
        grey = T.read_heightmap(gc_path).heights  # 1200 x 1200 grey levels
        metres = 700.0 + (grey - grey.min()) / np.ptp(grey) * 2000.0
        tile = np.pad(metres, ((0, 1), (0, 1)), mode="edge")  # 1201: 3 arc-seconds
        p = out / "N36W113.hgt"
        np.round(tile).astype(">i2").tofile(p)
        files["N36W113.hgt"] = (p, ground_spacing(36.5, -112.5, 1 / 1200, 1 / 1200))
        import imageio.v3 as iio

        crop = grey[400:764, 300:780]  # 364 x 480, the full 16-bit range
        p = out / "gcanyon_16bit.png"
        iio.imwrite(p, np.round((crop - crop.min()) / np.ptp(crop) * 65535).astype(np.uint16))
        files["gcanyon_16bit.png"] = (p, None)
    return files


def surface(heights: np.ndarray, mapping: dict, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """World y of the printed mapping's surface on the grid ``x`` (W,) by ``z`` (H,).

    Bilinear between sample centres, the edge samples extended outwards (separable
    ``np.interp``, which clamps at the ends), then faded into the flat apron beyond the
    map as the printed ``apron`` says -- NumPy only, no jaxgfx code.  At sample centres
    it returns the samples exactly.
    """
    if mapping.get("edge") != "apron":
        raise SystemExit(f"the reference builds apron maps only, got edge {mapping['edge']!r}")
    rows, cols = heights.shape
    (ox, oz), (cx, cz) = mapping["origin"], mapping["cell"]
    xs = ox + (np.arange(cols) + 0.5) * cx
    zs = oz + (np.arange(rows) + 0.5) * cz
    rel = (heights - heights.min()) * mapping["vertical_scale"]
    along_x = np.stack([np.interp(x, xs, row) for row in rel])  # (rows, W)
    grid = mapping["base"] + np.stack([np.interp(z, zs, col) for col in along_x.T], axis=1)
    ex = np.maximum(np.maximum(ox - x, x - (ox + cols * cx)), 0.0)  # (W,) voxels beyond
    ez = np.maximum(np.maximum(oz - z, z - (oz + rows * cz)), 0.0)
    t = np.clip(np.hypot(ex[None, :], ez[:, None]) / mapping["apron"]["fade"], 0.0, 1.0)
    w = t * t * (3.0 - 2.0 * t)
    return grid * (1.0 - w) + mapping["apron"]["y"] * w


def heightfield_mesh(
    heights: np.ndarray, mapping: dict, extent: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices and (F, 3) triangles of the full-resolution map over ``extent``.

    One vertex per sample centre inside ``extent = (x0, x1, z0, z1)``, plus the extent's
    border lines and, beyond the map, lines every half cell through the apron's fade
    (where the surface is curved), so that the mesh is the surface everywhere in the
    outer Clip-Box's footprint.
    """
    rows, cols = heights.shape
    x0, x1, z0, z1 = extent
    (ox, oz), (cx, cz) = mapping["origin"], mapping["cell"]
    fade = mapping["apron"]["fade"]

    def lines(o, c, count, lo, hi):
        centres = o + (np.arange(count) + 0.5) * c
        step = c / 2
        k = np.arange(1, int(np.ceil(fade / step)) + 1) * step
        apron = np.concatenate([[o, o + count * c], o - k, o + count * c + k])
        v = np.concatenate([[lo, hi], centres, apron])
        return np.unique(v[(v >= lo) & (v <= hi)])

    x = lines(ox, cx, cols, x0, x1)
    z = lines(oz, cz, rows, z0, z1)
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


def edge_views(terrain) -> dict[str, list[str]]:
    """Eight views beyond the map: 60 voxels outside each edge looking back at the map
    centre, and 60 voxels inside it looking out over the apron (yaw 0 looks along +z,
    90 along +x; row 0, the north edge, is at the smallest z)."""
    m = terrain.mapping
    (ox, oz), (cx, cz) = m.origin, m.cells
    w, d = m.shape[1] * cx, m.shape[0] * cz
    mx, mz = ox + w / 2, oz + d / 2
    apron = m.base + m.apron_height
    spots = {  # edge: (outside point, inside point, yaw towards the map)
        "west": ((ox - 60, mz), (ox + 60, mz), 90),
        "east": ((ox + w + 60, mz), (ox + w - 60, mz), 270),
        "north": ((mx, oz - 60), (mx, oz + 60), 0),
        "south": ((mx, oz + d + 60), (mx, oz + d - 60), 180),
    }
    views = {}
    for edge, ((x0, z0), (x1, z1), yaw) in spots.items():
        o = np.linspace(-3, 3, 7)
        g_out = float(np.max(np.asarray(T.ground_height(terrain, x0 + o, z0 + o[:, None]))))
        g_in = float(np.max(np.asarray(T.ground_height(terrain, x1 + o, z1 + o[:, None]))))
        y0 = int(max(apron, g_out)) + 30
        y1 = int(g_in) + 30
        views[f"{edge}_back"] = ["--viewer", f"{int(x0)},{y0},{int(z0)}", "--camera", f"{yaw},-15"]
        views[f"{edge}_out"] = [
            "--viewer",
            f"{int(x1)},{y1},{int(z1)}",
            "--camera",
            f"{(yaw + 180) % 360},-10",
        ]
    return views


def run_view(path, view, extra, size, out_dir, resolution=64, levels=5, options=()):
    """One CLI render + its reference; returns the row of numbers."""
    tag = f"{path.name.replace('.', '_')}_{view}"
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
    # The eye sits at the viewer, or (a height map's default view) where it sees the map
    # whole: the CLI prints both; its far plane reaches past the boxes from the eye.
    eye = np.asarray(rep["eye"], np.float64) - np.asarray(rep["viewer"], np.float64)
    far = 8.0 * (reach + float(np.linalg.norm(eye)))
    cam = camera_from_degrees(tuple(eye), yaw, pitch, 0.0, FOV, *size, 0.25, far)
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
    return row, rep


def scale_row(name: str, rep: dict, truth, relief: float) -> dict:
    """The printed scale of one map against the truth."""
    mps, mpv = rep["metres_per_sample"], rep["metres_per_voxel"]
    row = dict(
        map=name,
        crs=rep.get("crs"),
        shape=str(tuple(rep["shape"])),
        cell=str(tuple(round(c, 4) for c in rep["cell"])),
        metres_per_sample=None if mps is None else str(tuple(round(v, 2) for v in mps)),
        truth=None if truth is None else str(tuple(round(v, 2) for v in truth)),
        sample_error_pct=None,
        metres_per_voxel=None if mpv is None else str(tuple(round(v, 2) for v in mpv)),
        voxel_spread_pct=None,
        relief_voxels=round(relief, 1),
        width_voxels=round(rep["shape"][1] * rep["cell"][0], 1),
    )
    if mps is not None and truth is not None:
        row["sample_error_pct"] = 100 * float(np.max(np.abs(np.asarray(mps) / truth - 1)))
    if mpv is not None:
        row["voxel_spread_pct"] = 100 * float(np.ptp(mpv) / np.min(mpv))
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/heightmap_reference", help="output folder")
    p.add_argument("--size", default="320x240", help="WxH of every render")
    p.add_argument("--resolution", type=int, default=64, help="Clip-Box N (CLI default 64)")
    p.add_argument("--levels", type=int, default=5, help="Clip-Box levels (CLI default 5)")
    p.add_argument("--options", default="", help="more `jaxgfx terrain` options for every render")
    p.add_argument("--maps", default="", help="comma-separated subset of the maps' names")
    p.add_argument("--edges", action="store_true", help="add the eight views beyond the edges")
    p.add_argument("--views", default="", help="comma-separated subset of the views' names")
    p.add_argument("--quick", action="store_true", help="one map, one view, 160x120")
    args = p.parse_args(argv)
    size = (160, 120) if args.quick else tuple(int(v) for v in args.size.lower().split("x"))
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    maps: dict[str, tuple[Path, object]] = {}
    for name in ("SainteHelens.dem", "gcanyon_elev_crop.bw.png"):
        path = DATA / "terrain" / name
        if path.exists():
            maps[name] = (path, (30.0, 30.0) if name.endswith(".dem") else None)
        else:
            print(f"skipping {name}: {path} is absent (../shared/data)", file=sys.stderr)
    if not args.quick:
        maps.update(make_inputs(out_dir / "inputs"))
    else:
        maps = dict(list(maps.items())[:1])
    if args.maps:
        maps = {k: v for k, v in maps.items() if k in args.maps.split(",")}
    # quick: one view (each view's reference mesh has a size of its own: one more compile)
    views = {k: VIEWS[k] for k in ("low",)} if args.quick else VIEWS
    rows, scales = [], []
    for name, (path, truth) in maps.items():
        t = T.heightmap_terrain(path)
        relief = float(np.max(np.asarray(t.heights)))
        top = int(relief + t.mapping.base)
        todo = dict(views, **(edge_views(t) if args.edges else {}))
        if args.views:
            todo = {k: v for k, v in todo.items() if k in args.views.split(",")}
        for view, extra in todo.items():
            extra = [
                e.format(low=top // 2 + 40, high=top + 60, above=max(420, top + 100)) for e in extra
            ]
            row, rep = run_view(
                path,
                view,
                extra,
                size,
                out_dir,
                args.resolution,
                args.levels,
                args.options.split(),
            )
            rows.append(row)
            print(json.dumps(rows[-1]))
        scales.append(scale_row(name, rep, truth, relief))
        print(json.dumps(scales[-1]))
    cols = ["map", "view", "viewer", "camera", "reference_hit", "depth_ok", "masks_agree", "meets"]
    cols += [f"median_diff_{lo}" for lo, _ in BANDS]
    scols = ["map", "crs", "shape", "cell", "metres_per_sample", "truth", "sample_error_pct"]
    scols += ["metres_per_voxel", "voxel_spread_pct", "relief_voxels", "width_voxels"]
    md = "## Scale\n\n" + markdown_table(scales, scols)
    md += "\n\n## Renders against the reference\n\n" + markdown_table(rows, cols)
    md += f"\n\n{machine()}\n"
    met = sum(r["meets"] for r in rows)
    md += (
        f"\n{met} of {len(rows)} views meet depth >= {DEPTH_TARGET} and masks >= "
        f"{MASK_TARGET} (N = {args.resolution}, L = {args.levels}, {size[0]}x{size[1]}).\n"
    )
    title = "Clip-Box height maps against a full-resolution heightfield"
    write_table(out_dir, title, md, {"rows": rows, "scales": scales, "machine": machine()})
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
