"""Tests for ``jaxgfx flythrough`` (thesis 3.5.4): path, clearance, film, tables, errors."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from jaxgfx import terrain as T
from jaxgfx.cli import main
from jaxgfx.cli.flythrough import MARGIN, default_path, fly, path_frames
from jaxgfx.cli.terrain import make_terrain

# the Clip-Box and image sizes of test_terrain.py's CLI tests: their compiles are shared
TINY = ["--resolution", "16", "--levels", "2", "--size", "32x24", "--smoothing", "2"]


def test_path_frames_even_speed_and_heading():
    wp = np.array([[0.0, 5.0, 0.0], [30.0, 5.0, 0.0], [30.0, 5.0, 30.0]])
    pos, yaw = path_frames(wp, 7)
    # 60 voxels of track in 6 steps of 10
    np.testing.assert_allclose(np.linalg.norm(np.diff(pos, axis=0), axis=1), 10.0, atol=1e-9)
    np.testing.assert_allclose(pos[[0, 3, 6]], wp, atol=1e-9)
    # yaw 0 looks along +z, 90 along +x: the first leg heads +x, the last +z
    assert yaw[0] == pytest.approx(90.0, abs=1e-6)
    assert yaw[-1] == pytest.approx(0.0, abs=1e-6)
    assert np.all(np.diff(yaw) <= 1e-9)  # turns smoothly, one way


def test_default_heightmap_path_stays_above_the_ground(hill, tmp_path):
    h, _ = hill
    t = T.heightmap_terrain(h, cell=2, vertical_scale=0.5)
    wp, pitch = default_path(t, "heightmap:hill.npy", 16)
    pos, _ = path_frames(wp, 40)
    # NumPy reference of the surface: bilinear between sample centres, edges clamped
    m = t.mapping
    rel = (h - h.min()) * m.vertical_scale
    u = np.clip((pos[:, 0] - m.origin[0]) / m.cell - 0.5, 0, h.shape[1] - 1)
    v = np.clip((pos[:, 2] - m.origin[1]) / m.cell - 0.5, 0, h.shape[0] - 1)
    c0, r0 = np.minimum(u.astype(int), h.shape[1] - 2), np.minimum(v.astype(int), h.shape[0] - 2)
    fu, fv = u - c0, v - r0
    g = m.base + (
        rel[r0, c0] * (1 - fu) * (1 - fv)
        + rel[r0, c0 + 1] * fu * (1 - fv)
        + rel[r0 + 1, c0] * (1 - fu) * fv
        + rel[r0 + 1, c0 + 1] * fu * fv
    )
    assert np.all(pos[:, 1] - g >= MARGIN)
    assert pitch < 0
    # it crosses the map: from the south half to the north half
    assert pos[0, 2] > 0 > pos[-1, 2]


def test_cli_flythrough_heightmap_writes_film_and_tables(hill, tmp_path, capsys):
    import imageio.v3 as iio

    _, path = hill
    out, still = tmp_path / "fly.gif", tmp_path / "still.png"
    fn = ["--function", f"heightmap:{path}", "--cell", "2", "--vertical-scale", "0.5"]
    # No fog: at these tiny sizes fogged frames can be alike and the GIF merges them.
    args = ["flythrough", *TINY, *fn, "--frames", "3", "--fog", "0", "--out", str(out)]
    args += ["--still", str(still)]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    film = iio.imread(out)
    assert film.shape[:3] == (3, 24, 32)
    assert all(f.std() > 0 for f in film)  # terrain and sky, not a flat colour
    assert iio.imread(still).shape[:2] == (24, 32)
    table = json.loads((tmp_path / "fly.json").read_text())
    assert [r["frame"] for r in table["rows"]] == [0, 1, 2]
    for r in table["rows"]:
        assert r["ms"] > 0 and r["triangles"] > 0
        assert r["reuse_pct"] is None or 0 <= r["reuse_pct"] <= 100
    # Frame 0 stands where the worker built its boxes: nothing moves.  Each later frame is
    # ~15 voxels on, past both levels' move thresholds (N / 8 of their own voxels: 2 and
    # 4), and each frame waits for the worker: both boxes move, once.
    assert [r["boxes_updated"] for r in table["rows"]] == [0, 2, 2]
    assert summary["box_updates"] == 4
    md = (tmp_path / "fly.md").read_text()
    assert md.count("\n| ") == 4  # header + 3 frames
    assert summary["frames"] == 3 and summary["out"] == str(out)

    # The same boxes (so the compiles above are reused) under a camera that stands still
    # for a frame, jumps and stands still again: the jump updates every level once, and
    # no still frame updates any or counts the jump's updates again.
    t = make_terrain(f"heightmap:{path}", cell=2, vertical_scale=0.5)
    pipe = T.ClipBoxPipeline(t, size=16, levels=2, smoothing=2)
    wp, _ = default_path(t, "heightmap:hill.npy", 16)
    p, q = path_frames(wp, 3)[0][[0, 2]]
    frames, rows = fly(
        pipe, np.stack([p, p, q, q]), np.zeros(4), -15.0, size=(32, 24), fov=60.0,
        height_range=(0.0, 15.0), fog_distance=16.0, snow_line=None, wait=True,
    )  # fmt: skip
    assert [r["boxes_updated"] for r in rows] == [0, 0, 2, 0]
    assert [r["generation"] for r in rows] == [0, 0, 1, 1]
    assert np.array_equal(frames[0], frames[1]) and np.array_equal(frames[2], frames[3])
    assert not np.array_equal(frames[1], frames[2])


def test_cli_flythrough_errors(hill, tmp_path, capsys):
    _, hill_npy = hill
    gif = str(tmp_path / "f.gif")
    fn = ["--function", f"heightmap:{hill_npy}", "--cell", "2", "--vertical-scale", "0.5"]
    cases = [
        (["--out", str(tmp_path / "f.png")], "--out"),
        (["--out", gif, "--still", str(tmp_path / "s.jpg")], "--still"),
        (["--out", gif, "--frames", "0"], "--frames"),
        (["--out", gif, "--path", "1,2"], "--path"),
        (["--out", gif, "--path", "1,2,3,1,2,3"], "--path"),
        (["--out", gif, "--path", "0,50,0,1e12,50,0"], "--path"),
        (["--out", gif, "--cell", "2"], "--cell"),
        (["--out", gif, "--resolution", "12"], "--resolution"),
        (["--out", gif, "--pitch", "95"], "--pitch"),
        (["--out", str(tmp_path / "no" / "f.gif")], "--out"),
        # below the hill's top (world y up to 15) at the map centre
        ([*fn, "--out", gif, "--path", "0,3,0,10,3,0"], "voxels above the ground"),
        # f_SAW is solid at (x + y + z) mod 1000 < 500: y = 24 is inside a slab
        (["--function", "saw", "--out", gif, "--path", "0,24,0,10,24,0"], "solid ground"),
    ]
    if importlib.util.find_spec("imageio_ffmpeg") is None:
        cases.append((["--out", str(tmp_path / "f.mp4")], "imageio-ffmpeg"))
    for extra, needle in cases:
        assert main(["flythrough", *TINY, *extra]) == 2, extra
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, (extra, err)
    assert not list(tmp_path.glob("f.*"))
