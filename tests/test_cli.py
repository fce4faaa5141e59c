"""The jaxgfx command line, called in-process."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import trimesh

from jaxgfx.cli import main


def test_info(capsys):
    import jax

    import jaxgfx

    assert main(["info"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["jaxgfx"] == jaxgfx.__version__ and info["jax"] == jax.__version__
    assert info["backend"] == jax.default_backend()
    assert info["devices"] == [str(d) for d in jax.devices()]
    assert info["local_devices"] == jax.local_device_count() >= 1


def test_demo_writes_images_and_timing(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--size", "48x32", "--out", str(out)]) == 0
    color = iio.imread(out / "color.png")
    depth = iio.imread(out / "depth.png")
    assert color.shape == (32, 48, 3) and depth.shape == (32, 48)
    assert color.std() > 5  # a picture, not a flat fill
    assert depth.max() > depth.min()
    timing = json.loads((out / "timing.json").read_text())
    assert {r["stage"] for r in timing["stages"]} >= {"polygon pass (rasterizer)", "frame total"}
    assert "| stage |" in (out / "timing.md").read_text()


def test_render_mesh_with_depth(tmp_path, capsys):
    mesh_file = tmp_path / "ico.ply"
    trimesh.creation.icosphere(subdivisions=2).export(mesh_file)
    png, npy = tmp_path / "f.png", tmp_path / "d.npy"
    rc = main(["render", str(mesh_file), "--size", "40x30", "--out", str(png), "--depth", str(npy)])
    assert rc == 0
    d = np.load(npy)
    assert d.shape == (30, 40) and np.isfinite(d).any() and np.isinf(d).any()
    assert iio.imread(png).shape == (30, 40, 3)
    # explicit camera: x,y,z,yaw,pitch -- looking away from the mesh sees nothing
    rc = main(
        ["render", str(mesh_file), "--camera", "0,0,5,0,0", "--size", "16x12",
         "--out", str(png), "--depth", str(npy)]
    )  # fmt: skip
    assert rc == 0 and np.all(np.isinf(np.load(npy)))


def test_cli_errors(tmp_path, capsys):
    assert main(["render", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x.png")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["demo", "--size", "0x10"]) == 2
    err = capsys.readouterr().err
    assert "error: argument --size: size must be positive" in err
    assert main(["render", "m.ply", "--camera", "1,2,3"]) == 2
    assert "error: argument --camera: expected 5 finite" in capsys.readouterr().err
    assert main(["sweep", "m.ply", "--n", "0"]) == 2
    assert "jaxgfx sweep: error: --n must be positive" in capsys.readouterr().err
    assert main([]) == 2  # no subcommand: help, exit 2


def test_negative_camera_values_need_no_equals(tmp_path, capsys):
    mesh_file = tmp_path / "ico.ply"
    trimesh.creation.icosphere(subdivisions=1).export(mesh_file)
    npy = tmp_path / "d.npy"
    rc = main(
        ["render", str(mesh_file), "--camera", "-0.5,0,-5,0,0", "--size", "16x12",
         "--out", str(tmp_path / "f.png"), "--depth", str(npy)]
    )  # fmt: skip
    assert rc == 0 and np.isfinite(np.load(npy)).any()  # looks along +z at the sphere
