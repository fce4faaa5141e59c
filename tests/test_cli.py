"""The jaxgfx command line, called in-process."""

from __future__ import annotations

import argparse
import json
import os

import imageio.v3 as iio
import jax
import numpy as np
import pytest
import trimesh

import jaxgfx.cli
from jaxgfx.cli import build_parser, main


@pytest.fixture
def ico(tmp_path):
    path = tmp_path / "ico.ply"
    trimesh.creation.icosphere(subdivisions=0).export(path)
    return str(path)


def test_info(capsys):
    import jax

    import jaxgfx

    assert main(["info"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["jaxgfx"] == jaxgfx.__version__ and info["jax"] == jax.__version__
    assert info["backend"] == jax.default_backend()
    assert info["devices"] == [str(d) for d in jax.devices()]
    assert info["local_devices"] == jax.local_device_count() >= 1


def test_render_mesh_with_depth(tmp_path, capsys, ico):
    # ico at 16x12: the size of every small render here, so a worker compiles it once
    png, npy = tmp_path / "f.png", tmp_path / "d.npy"
    rc = main(["render", ico, "--size", "16x12", "--out", str(png), "--depth", str(npy)])
    assert rc == 0
    d = np.load(npy)
    assert d.shape == (12, 16) and np.isfinite(d).any() and np.isinf(d).any()
    assert iio.imread(png).shape == (12, 16, 3)
    # explicit camera: x,y,z,yaw,pitch -- looking away from the mesh sees nothing
    rc = main(
        ["render", ico, "--camera", "0,0,5,0,0", "--size", "16x12",
         "--out", str(png), "--depth", str(npy)]
    )  # fmt: skip
    assert rc == 0 and np.all(np.isinf(np.load(npy)))
    assert "lies behind the camera" in capsys.readouterr().err  # and says so


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


def test_negative_camera_values_need_no_equals(tmp_path, capsys, ico):
    npy = tmp_path / "d.npy"
    rc = main(
        ["render", ico, "--camera", "-0.5,0,-5,0,0", "--size", "16x12",
         "--out", str(tmp_path / "f.png"), "--depth", str(npy)]
    )  # fmt: skip
    assert rc == 0 and np.isfinite(np.load(npy)).any()  # looks along +z at the sphere


def test_cache_dir_and_no_cache(tmp_path, capsys, cache_calls, monkeypatch):
    assert main(["info"]) == 0
    assert cache_calls == [tmp_path / "jax-cache"]
    assert main(["--no-cache", "info"]) == 0
    assert len(cache_calls) == 1  # --no-cache skips it
    assert jaxgfx.cli.cache_dir({"XDG_CACHE_HOME": "/x"}) == jaxgfx.cli.Path("/x/jaxgfx/jax")
    assert (
        jaxgfx.cli.cache_dir({"JAXGFX_CACHE_DIR": "/y", "XDG_CACHE_HOME": "/x"}).as_posix() == "/y"
    )
    home = jaxgfx.cli.cache_dir({})
    assert home.parts[-3:] == (".cache", "jaxgfx", "jax")


def test_enable_compilation_cache_sets_jax_config(tmp_path, monkeypatch):
    import importlib

    import jax

    cli = importlib.reload(jaxgfx.cli)  # the real function, not the fixture's recorder
    updates: dict = {}
    monkeypatch.setattr(jax.config, "update", lambda k, v: updates.__setitem__(k, v))
    assert cli.enable_compilation_cache(tmp_path / "c" / "jax")
    assert updates == {
        "jax_compilation_cache_dir": str(tmp_path / "c" / "jax"),
        "jax_persistent_cache_min_compile_time_secs": 0.0,
        "jax_persistent_cache_min_entry_size_bytes": -1,
    }
    (tmp_path / "file").write_text("")
    assert not cli.enable_compilation_cache(tmp_path / "file" / "jax")  # cannot create: skip


def test_every_option_has_help():
    def walk(parser: argparse.ArgumentParser, name: str):
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            if isinstance(action, argparse._SubParsersAction):
                for sub_name, sub in action.choices.items():
                    yield from walk(sub, sub_name)
                continue
            yield name, action

    seen = 0
    for name, action in walk(build_parser(), "jaxgfx"):
        seen += 1
        assert action.help and action.help.strip(), f"{name} {action.option_strings or action.dest}"
    assert seen > 40


_COMPILES: list[str] = []  # the JAX programs traced while _refused watches (its listener)


def _count_compiles(event: str, duration: float, **kwargs) -> None:
    # Tracing comes before compiling and before a persistent-cache hit, so it counts both.
    if event == "/jax/core/compile/jaxpr_trace_duration" and _COMPILES and _COMPILES[0] == "on":
        _COMPILES.append(str(kwargs.get("fun_name", "?")))


jax.monitoring.register_event_duration_secs_listener(_count_compiles)


def _refused(argv) -> None:
    """``main(argv)`` refuses with exit code 2 before any work: no JAX program is traced.

    (Counted, not timed: a wall-clock bound fails on a loaded machine.)
    """
    _COMPILES[:] = ["on"]
    try:
        assert main(argv) == 2, argv
    finally:
        compiled = _COMPILES[1:]
        _COMPILES.clear()
    assert not compiled, (argv, compiled)


def _error_line(capsys, *words: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err and "error:" in lines[0]
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def test_bad_output_paths(tmp_path, capsys, ico):
    d = tmp_path / "dir"
    d.mkdir()
    f = tmp_path / "file.txt"
    f.write_text("")
    missing = tmp_path / "nope" / "x.png"
    cases = [
        (["render", ico, "--out", str(tmp_path / "r.jpg")], "--out", ".png"),
        (["render", ico, "--out", str(missing)], "--out", "does not exist"),
        (["render", ico, "--out", str(d)[:-3] + "x.png"], "--out", "is a directory"),
        (["render", ico, "--out", str(f)], "--out", ".png"),
        (["render", ico, "--out", str(tmp_path / "a.png"), "--depth", str(tmp_path / "d.png")],
         "--depth", ".npy"),
        (["render", ico, "--out", str(tmp_path / "a.png"), "--depth", str(missing)[:-4] + ".npy"],
         "--depth", "does not exist"),
        (["demo", "--out", str(f)], "--out", "expected a directory"),
        (["demo", "--out", str(missing)], "--out", "does not exist"),
        (["sweep", ico, "--out", str(f)], "--out", "expected a directory"),
        (["skin", "--out", str(f)], "--out", "expected a directory"),
        (["terrain", "--out", str(tmp_path / "t.bmp")], "--out", ".png"),
        (["terrain", "--out", str(tmp_path / "t.png"), "--mesh", str(tmp_path / "m.fbx")],
         "--mesh", ".ply"),
        (["terrain", "--out", str(tmp_path / "t.png"), "--mesh", str(missing)[:-4] + ".ply"],
         "--mesh", "does not exist"),
        (["voxelize", "tree", "--resolution", "8", "--out", str(tmp_path / "s.vox")],
         "--out", ".npz"),
        (["render-voxels", "s.npz", "--camera", "0,0,0,0,0", "--out", str(f)], "--out", ".png"),
    ]  # fmt: skip
    (tmp_path / "x.png").mkdir()
    for argv, option, words in cases:
        _refused(argv)
        _error_line(capsys, option, words)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["dir", "file.txt", "ico.ply", "x.png"]
    )  # nothing was written


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_unwritable_output(tmp_path, capsys, ico):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        assert main(["render", ico, "--out", str(ro / "r.png")]) == 2
        _error_line(capsys, "--out", "not writable")
        assert main(["demo", "--out", str(ro)]) == 2
        _error_line(capsys, "--out", "not writable")
    finally:
        ro.chmod(0o700)


def test_sizes_beyond_memory(tmp_path, capsys, ico):
    png = str(tmp_path / "a.png")
    cases = [
        (["render", ico, "--size", "100000x100000", "--out", png], "--size"),
        (["demo", "--size", "100000x100000", "--out", str(tmp_path / "d")], "--size"),
        (["sweep", ico, "--size", "20000x20000", "--out", str(tmp_path / "s")], "--size"),
        (["skin", "--size", "100000x100000", "--out", str(tmp_path / "k")], "--size"),
        (["render-voxels", "s.npz", "--camera", "0,0,0,0,0", "--size", "20000x20000",
          "--out", png], "--size"),
        (["terrain", "--resolution", "4096", "--out", png], "--resolution"),
        (["voxelize", "tree", "--resolution", "100000", "--out", str(tmp_path / "s.npz")],
         "--resolution"),
    ]  # fmt: skip
    for argv, option in cases:
        _refused(argv)
        _error_line(capsys, option, "GiB", "limit")


def test_bad_numbers(tmp_path, capsys, ico):
    png = str(tmp_path / "a.png")
    cam = ["--camera", "0,0,0,0,0"]
    cases = [
        (["render", ico, "--fov", "0", "--out", png], "--fov"),
        (["render", ico, "--fov", "180", "--out", png], "--fov"),
        (["render", ico, "--fov", "-5", "--out", png], "--fov"),
        (["render", ico, "--fov", "nan", "--out", png], "--fov"),
        (["sweep", ico, "--fov", "0"], "--fov"),
        (["sweep", ico, "--elevation", "90"], "--elevation"),
        (["terrain", "--fov", "200"], "--fov"),
        (["render-voxels", "s.npz", *cam, "--fov", "0", "--out", png], "--fov"),
        (["render-voxels", "s.npz", *cam, "--far", "0", "--out", png], "--far"),
        (["render-voxels", "s.npz", *cam, "--refine", "-1", "--out", png], "--refine"),
        (["render-voxels", "s.npz", *cam, "--oversample", "0", "--out", png], "--oversample"),
        (["render-voxels", "s.npz", *cam, "--lod", "-1", "--out", png], "--lod"),
        (["render-voxels", "s.npz", *cam, "--buffer-size", "0", "--out", png], "--buffer-size"),
        (["terrain", "--mesh-level", "7", "--out", png, "--mesh", str(tmp_path / "m.ply")],
         "--mesh-level"),
        (["terrain", "--mesh-level", "1", "--out", png], "--mesh-level"),
        (["terrain", "--mesh-level", "-1"], "--mesh-level"),
        (["terrain", "--resolution", "12", "--out", png], "--resolution"),
        (["terrain", "--levels", "0"], "--levels"),
        (["terrain", "--smoothing", "-1"], "--smoothing"),
        (["terrain", "--cell", "0"], "--cell"),
        (["terrain", "--vertical-scale", "0"], "--vertical-scale"),
        (["voxelize", "tree", "--resolution", "8", "--levels", "20",
          "--out", str(tmp_path / "s.npz")], "--levels"),
        (["skin", "--bend", "1e30"], "--bend"),
        (["skin", "--twist", "-361"], "--twist"),
        (["skin", "--bend", "inf"], "--bend"),
        (["sweep", ico, "--n", "0"], "--n"),
        (["sweep", ico, "--devices", "0"], "--devices"),
        (["sweep", ico, "--devices", "4096", "--out", str(tmp_path / "s")], "--devices"),
        (["demo", "--frames", "-1"], "--frames"),
        (["demo", "--frames", "100000"], "--frames"),
        (["demo", "--data", str(tmp_path / "nowhere"), "--out", str(tmp_path)], "--data"),
    ]  # fmt: skip
    for argv, option in cases:
        _refused(argv)
        _error_line(capsys, option)
    assert list(tmp_path.iterdir()) == [tmp_path / "ico.ply"]


def test_levels_beyond_a_saved_scene(tmp_path, capsys):
    scene = tmp_path / "s.npz"
    np.savez(scene, coords=np.zeros((1, 3), np.int64), colors=np.zeros((1, 3), np.uint8),
             shape=np.array([4, 4, 4]))  # fmt: skip
    argv = ["render-voxels", str(scene), "--camera", "2,2,-10,0,0", "--levels", "4",
            "--out", str(tmp_path / "a.png")]  # fmt: skip
    assert main(argv) == 2
    _error_line(capsys, "--levels", "<= 3")


# ---------------------------------------------------------------- real inputs: glTF rigs, --up


def _orange_share(png) -> float:
    """Share of the frame drawn in the character colour (red well above blue; sky, ground
    and the grey stand are not)."""
    img = iio.imread(png).astype(int)
    return float(((img[..., 0] - img[..., 2]) > 30).mean())


def test_render_skinned_glb_shows_the_fox(tmp_path, capsys, data_dir):
    fox = str(data_dir / "rigs" / "fox.glb")
    png = tmp_path / "fox.png"
    assert main(["render", fox, "--time", "1.0", "--size", "48x36", "--out", str(png)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["skinned_vertices"] == 1728 and summary["props"] == 4
    assert _orange_share(png) >= 0.02  # the fox shows: at least 2 % of the frame
    cases = [
        (["render", fox, "--time", "99", "--out", str(png)], "--time", "outside the clip"),
        (["render", fox, "--time", "-1", "--out", str(png)], "--time"),
        (["render", fox, "--up", "w", "--out", str(png)], "--up"),
    ]
    for argv, *words in cases:
        _refused(argv)
        _error_line(capsys, *words)


def test_skin_rig_lbs_and_spline(tmp_path, capsys, data_dir):
    fox = str(data_dir / "rigs" / "fox.glb")
    for method in ("lbs", "spline"):
        out = tmp_path / method
        argv = ["skin", "--rig", fox, "--method", method, "--time", "2", "--size", "32x24"]
        assert main([*argv, "--out", str(out)]) == 0
        img = iio.imread(out / "skin.png")
        assert img.shape == (24, 32, 3) and (img.min(-1) < 200).mean() > 0.05  # the fox drawn
    assert "spline (style muscle)" in capsys.readouterr().out
    out = str(tmp_path / "e")
    cases = [
        (["skin", "--method", "lbs", "--style", "muscle"], "--style", "no deformation styles"),
        (["skin", "--method", "dqs", "--style", "muscle"], "--style"),
        (["skin", "--rig", fox, "--method", "lbs", "--style", "muscle"], "--style"),
        (["skin", "--time", "1"], "--time", "--rig"),
        (["skin", "--chain", "a,b,c"], "--chain", "--rig"),
        (["skin", "--rig", fox, "--bend", "30"], "--bend"),
        (["skin", "--rig", fox, "--method", "lbs", "--chain", "b_Tail01,b_Tail02,b_Tail03"],
         "--chain"),
        (["skin", "--rig", str(tmp_path / "missing.glb")], "--rig", "no such file"),
        (["skin", "--rig", fox, "--time", "99"], "--time", "outside the clip"),
        (["skin", "--rig", fox, "--chain", "b_Tail01,b_Tail02,b_Nope"], "--chain", "b_Nope"),
        (["skin", "--rig", fox, "--chain", "b_Tail01,b_Tail02"], "--chain", "three"),
    ]  # fmt: skip
    for argv, *words in cases:
        _refused([*argv, "--out", out])
        _error_line(capsys, *words)
    assert not os.path.exists(out)


def test_render_time_needs_a_skinned_glb(tmp_path, capsys, ico):
    assert main(["render", ico, "--time", "1", "--out", str(tmp_path / "a.png")]) == 2
    _error_line(capsys, "--time", "skinned")


def test_load_mesh_up_axis(tmp_path):
    from jaxgfx.io import load_mesh, up_rotation

    path = tmp_path / "box.ply"
    trimesh.creation.box(extents=(1.0, 2.0, 5.0)).export(path)  # a z-up scan: tall along z
    np.testing.assert_allclose(load_mesh(path).extents, [1.0, 2.0, 5.0], atol=1e-6)
    np.testing.assert_allclose(load_mesh(path, up="z").extents, [1.0, 5.0, 2.0], atol=1e-6)
    np.testing.assert_allclose(load_mesh(path, up="x").extents, [2.0, 1.0, 5.0], atol=1e-6)
    for axis, col in (("x", 0), ("y", 1), ("z", 2)):
        r = up_rotation(axis)
        assert np.isclose(np.linalg.det(r), 1.0)  # a rotation: faces keep their winding
        np.testing.assert_allclose(r[:, col], [0.0, 1.0, 0.0])  # that axis becomes +y
    assert load_mesh(path, up="z").is_winding_consistent
    with pytest.raises(ValueError, match="up must be"):
        load_mesh(path, up="-z")


def test_render_up_z_stands_a_scan_upright(tmp_path):
    path = tmp_path / "box.ply"
    trimesh.creation.box(extents=(2.0, 1.0, 6.0)).export(path)  # a z-up scan: tall along z
    npy = tmp_path / "d.npy"
    argv = ["render", str(path), "--up", "z", "--size", "24x24", "--depth", str(npy)]
    assert main([*argv, "--out", str(tmp_path / "a.png")]) == 0
    rows, cols = np.nonzero(np.isfinite(np.load(npy)))
    # upright: the silhouette is 6 : 2 tall (lying, as y-up, it is about as tall as wide: 9 : 9)
    assert np.ptp(rows) > 2.0 * np.ptp(cols)


def test_up_alone_suffices_and_render_takes_front(tmp_path, capsys, ico):
    from jaxgfx import raycast as V

    # a z-up slab, broad along the file's x and z: voxelized facing +z, thin along z
    path = tmp_path / "slab.ply"
    trimesh.creation.box(extents=(4.0, 0.5, 3.0)).export(path)
    scene = tmp_path / "s.npz"
    assert main(["voxelize", str(path), "--up", "z", "--resolution", "8", "--out", str(scene)]) == 0
    shape = V.load_scene(str(scene)).shape
    assert shape[2] == min(shape), shape
    assert build_parser().parse_args(["render", ico, "--front=-x"]).front == "-x"
    out = str(tmp_path / "f.png")
    assert main(["render", ico, "--up", "z", "--front", "z", "--out", out]) == 2
    assert "--front z is the --up axis (z)" in capsys.readouterr().err
    argv = ["voxelize", str(path), "--up", "z", "--front", "z", "--resolution", "8"]
    assert main([*argv, "--out", str(scene)]) == 2
    assert "--front z is the --up axis (z)" in capsys.readouterr().err


def test_host_device_flags():
    from jaxgfx.cli import host_device_flags

    flag = "--xla_force_host_platform_device_count"
    assert host_device_flags({}, None, 8) == f"{flag}=8"  # one device per core
    assert host_device_flags({}, 3, 8) == f"{flag}=3"  # --devices
    assert host_device_flags({"XLA_FLAGS": "--xla_cpu_foo=1"}, None, 4) == (
        f"--xla_cpu_foo=1 {flag}=4"
    )  # other flags kept
    assert host_device_flags({"XLA_FLAGS": f"{flag}=2"}, None, 8) is None  # the user's count
    assert host_device_flags({"XLA_FLAGS": f"{flag}=2"}, 6, 8) is None
    assert host_device_flags({"JAX_PLATFORMS": "cuda"}, None, 8) is None  # not the CPU
    assert host_device_flags({"JAX_PLATFORMS": "cpu"}, None, 8) == f"{flag}=8"
    assert host_device_flags({}, None, 1) is None  # one core: nothing to add


def test_lost_elements_warning_names_the_size_that_keeps_them(capsys):
    from jaxgfx.camera import look_at
    from jaxgfx.cli.voxels import warn_lost_elements

    cam = look_at([0, 0, -10], [0, 0, 0], 60, 40, 30)

    def said(lost, drawn):
        warn_lost_elements({"buffer_overflow": lost, "elements_rendered": drawn}, cam)
        return capsys.readouterr().err

    assert said(0, 900) == ""
    # A plane's list was full: one entry per row of the longest plane (max(W, H)) fits.
    told = said(30, 900)
    assert "30 of the 900" in told and "--buffer-size 40" in told


# ------------------------------------------------- inputs that are not what they claim to be


def test_inputs_that_are_not_what_they_claim_are_named(tmp_path, capsys, ico):
    folder = tmp_path / "folder"
    folder.mkdir()
    cloud = tmp_path / "cloud.ply"  # 100 vertices, no faces
    trimesh.PointCloud(np.random.default_rng(0).uniform(size=(100, 3))).export(cloud)
    slc = tmp_path / "x.slc"
    slc.write_bytes(b"\0" * 100)
    fake = tmp_path / "fake.npz"
    fake.write_text("not a zip\n")
    png, npz, d = str(tmp_path / "o.png"), str(tmp_path / "o.npz"), str(folder)
    cases = [
        (["render-voxels", ico, "--out", png], "is a mesh", "voxelize it first"),
        (["render-voxels", str(slc), "--out", png], "'.slc'", "scene .npz"),
        (["render-voxels", str(fake), "--out", png], "not a scene .npz"),
        (["render-voxels", d, "--out", png], "is a directory"),
        (["render", d, "--out", png], "mesh", "is a directory"),
        (["sweep", d, "--out", str(tmp_path / "sw")], "mesh", "is a directory"),
        (["voxelize", d, "--resolution", "8", "--out", npz], "is a directory"),
        (["skin", "--rig", d, "--out", str(tmp_path / "sk")], "--rig", "is a directory"),
        (["render", str(cloud), "--out", png], "100 points", "point cloud"),
        (["voxelize", str(slc), "--resolution", "64", "--out", npz],
         "'.slc'", "volumes (.mhd", ".kv6", "'tree'"),
    ]  # fmt: skip
    for argv, *words in cases:
        _refused(argv)
        _error_line(capsys, *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["folder", "cloud.ply", "x.slc", "fake.npz", "ico.ply"]
    )  # nothing was written


def test_a_truncated_binary_ply_is_named_truncated(tmp_path, capsys):
    from jaxgfx.io import load_mesh

    data = trimesh.creation.icosphere(subdivisions=1).export(file_type="ply")  # 42 v, 80 f
    start = data.index(b"end_header\n") + len(b"end_header\n")
    cut = tmp_path / "cut.ply"
    cases = {
        # in the faces, where trimesh says "PLY is unexpected length!"
        len(data) - 100: "42 of 42 vertices, 72 of 80 faces complete",
        # between vertices and faces, where trimesh reads the vertices alone (no faces)
        start + 42 * 12: "42 of 42 vertices, 0 of 80 faces complete",
        start + 5 * 12 + 7: "5 of 42 vertices complete",
    }
    for size, found in cases.items():
        cut.write_bytes(data[:size])
        with pytest.raises(ValueError, match="declares 42 vertices and 80 faces") as err:
            load_mesh(cut)
        assert "is truncated" in str(err.value) and found in str(err.value)
        assert "empty" not in str(err.value) and "point cloud" not in str(err.value)
    # faces of different lengths (a triangle, then a quad), big-endian: walked row by row
    head = b"ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty float x\n"
    head += b"property float y\nproperty float z\nelement face 2\n"
    head += b"property list uchar int vertex_indices\nend_header\n"
    body = np.arange(12, dtype=">f4").tobytes() + bytes([3]) + np.arange(3, dtype=">i4").tobytes()
    body += bytes([4]) + np.arange(4, dtype=">i4").tobytes()
    cut.write_bytes(head + body[:-2])
    with pytest.raises(ValueError, match="4 of 4 vertices, 1 of 2 faces complete"):
        load_mesh(cut)
    cut.write_bytes(head + body)  # whole (trimesh reads no lists of mixed lengths)
    with pytest.raises(ValueError) as err:
        load_mesh(cut)
    assert "is truncated" not in str(err.value)
    # the command line says the same in one line
    cut.write_bytes(data[: len(data) - 100])
    _refused(["render", str(cut), "--out", str(tmp_path / "o.png")])
    _error_line(capsys, "is truncated", "declares 42 vertices and 80 faces", "ends early")


@pytest.mark.skipif(not os.path.isdir("/sys"), reason="needs Linux's /sys")
def test_outputs_are_tried_not_just_permission_checked(capsys, ico):
    # /sys passes os.access for root, yet no file can be created in it: tried, refused.
    for argv in (
        ["render", ico, "--out", "/sys/o.png"],
        ["render", ico, "--out", "/tmp/o.png", "--depth", "/sys/d.npy"],
        ["demo", "--out", "/sys/demo"],
        ["sweep", ico, "--out", "/sys/sweep"],
        ["voxelize", "tree", "--resolution", "8", "--out", "/sys/t.npz"],
    ):
        _refused(argv)
        _error_line(capsys, "--", "cannot create a file in '/sys'")


# ------------------------------- one compiled render (ico, 16x12) shared by the checks below


def _collinear_copy(ico: str, path) -> str:
    """The ico with every vertex on the x axis: same shapes, every triangle of zero area."""
    m = trimesh.load(ico, process=False)
    v = np.asarray(m.vertices).copy()
    v[:, 1:] = 0.0
    trimesh.Trimesh(v, m.faces, process=False).export(path)
    return str(path)


def test_render_warns_on_empty_frames_and_reports_write_errors(tmp_path, capsys, ico, monkeypatch):
    import errno

    import jaxgfx.io

    png, npy = str(tmp_path / "a.png"), str(tmp_path / "d.npy")
    small = ["--size", "16x12", "--out", png, "--depth", npy]
    assert main(["render", ico, *small]) == 0
    assert capsys.readouterr().err == ""  # a framed subject: no warning
    # A field of view that leaves the mesh smaller than a pixel: drawn empty, said so.
    assert main(["render", ico, *small, "--fov", "179.9"]) == 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "warning: the frame is empty" in err
    assert "pixels at --fov 179.9" in err and not np.isfinite(np.load(npy)).any()
    # A degenerate mesh: nothing drawn, and the cause named.
    flat = _collinear_copy(ico, tmp_path / "flat.ply")
    assert main(["render", flat, *small]) == 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "zero area" in err

    # A write that fails after the work: one line naming the output and the cause, exit 1.
    def full_disk(path, img):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(jaxgfx.io, "save_png", full_disk)
    assert main(["render", ico, *small]) == 1
    _error_line(capsys, "--out", "could not write it: No space left on device")
    # A bug inside is not a usage error: it keeps its traceback (it reaches the caller).
    import jaxgfx.cli.render

    def broken(*args):
        raise ValueError("an internal bug")

    monkeypatch.setattr(jaxgfx.cli.render, "_frame_jit", lambda: broken)
    with pytest.raises(ValueError, match="an internal bug"):
        main(["render", ico, *small])


# ---------------------------------------------------------------- sweeps: Ctrl-C, bytes, sheet


def test_sweep_ctrl_c_keeps_chunks_says_how_to_resume_and_stays_small(tmp_path, capsys, ico):
    import jaxgfx._src.sweep as sweep_impl
    from jaxgfx.sweep import load_sweep

    out = tmp_path / "sw"
    argv = ["sweep", ico, "--n", "4", "--chunk", "2", "--devices", "1", "--size", "160x120",
            "--out", str(out)]  # fmt: skip
    run, calls = sweep_impl._run, []

    def interrupted_run(*args):  # Ctrl-C while the second chunk renders
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return run(*args)

    sweep_impl._run = interrupted_run
    try:
        assert main(argv) == 130
    finally:
        sweep_impl._run = run
    cap = capsys.readouterr()
    line = cap.err.strip().splitlines()[-1]
    assert "Traceback" not in cap.err
    assert line.startswith("jaxgfx sweep: interrupted: 2 of 4 frames are kept in")
    assert "run the same command again" in line
    assert main(argv) == 0  # the same command resumes
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["skipped"] == 1 and summary["computed"] == 1
    data = load_sweep(out / "chunks")
    assert data["color"].shape == (4, 120, 160, 3) and data["depth"].dtype == np.float32
    for i in range(4):  # the frames are the stored colour, bit for bit
        np.testing.assert_array_equal(iio.imread(out / f"frame_{i:05d}.png"), data["color"][i])
    # Compact: colour as PNG, depth compressed: under the bound of 100 MB for 1,000 frames
    # at 320x240, 1.3 bytes a pixel (raw colour and depth took 7; experiments/sweep_storage
    # measures the full size).
    files = [p for p in out.rglob("*") if p.is_file()]
    stored = sum(p.stat().st_size for p in files if p.name != "contact_sheet.png")
    assert stored / (4 * 160 * 120) < 100e6 / (1000 * 320 * 240)
    assert summary["bytes"] == sum(p.stat().st_size for p in files)


def test_contact_sheet_is_capped():
    from jaxgfx.cli.render import SHEET_SIDE, SHEET_TILES, contact_sheet, sheet_layout

    picks, cols, shrink = sheet_layout(1000, (320, 240))
    assert len(picks) == SHEET_TILES and picks[0] == 0 and picks[-1] == 999
    rows = -(-len(picks) // cols)
    assert max(cols * 320, rows * 240) // shrink <= SHEET_SIDE
    assert sheet_layout(8, (20, 16)) == (list(range(8)), 6, 1)  # small sweeps: every frame
    imgs = np.random.default_rng(0).integers(0, 255, (5, 4, 6, 3), dtype=np.uint8)
    sheet = contact_sheet(imgs, 3, shrink=2)
    assert sheet.shape == (4, 9, 3)  # 2 rows of 2x3 tiles
    np.testing.assert_allclose(sheet[0, 0], imgs[0, :2, :2].reshape(-1, 3).mean(0), atol=0.51)


# ---------------------------------------------------------------- default views frame subjects


def _framed(depth: np.ndarray, fill: float = 0.7) -> None:
    """The subject (finite depth) lies inside the frame with a margin on every side and fills
    at least ``fill`` of the width or the height."""
    h, w = depth.shape
    rows, cols = np.nonzero(np.isfinite(depth))
    assert len(rows), "the frame is empty"
    free = (rows.min() / h, cols.min() / w, (h - 1 - rows.max()) / h, (w - 1 - cols.max()) / w)
    assert min(free) >= 0.02, f"cropped or touching the edge: top, left, bottom, right {free}"
    assert max(np.ptp(rows) / h, np.ptp(cols) / w) >= fill, "the subject is small in the frame"


def test_voxel_tree_default_view_frames_it(tmp_path, capsys):
    scene, npy = str(tmp_path / "t.npz"), str(tmp_path / "d.npy")
    assert main(["voxelize", "tree", "--resolution", "16", "--out", scene]) == 0
    argv = ["render-voxels", scene, "--reference", "--size", "32x24", "--depth", npy]
    assert main([*argv, "--out", str(tmp_path / "t.png")]) == 0
    _framed(np.load(npy))
    img = iio.imread(tmp_path / "t.png")
    assert img[0, :, 2].min() > 150  # a sky behind, not black


def test_default_views_frame_the_fox_the_head_and_the_bunny(tmp_path, capsys, data_dir):
    from jaxgfx import raycast as V

    npy = str(tmp_path / "d.npy")
    small = ["--size", "32x24", "--depth", npy]
    # The fox, skinned, at five times of its clip (its head is never cut off).
    fox = str(data_dir / "rigs" / "fox.glb")
    for t in ("0", "1.5", "3", "6", "8.7"):
        argv = ["skin", "--rig", fox, "--method", "lbs", "--time", t, *small]
        assert main([*argv, "--out", str(tmp_path / "skin")]) == 0
        _framed(np.load(npy))
    # The bunny (the README's render).
    bunny = str(data_dir / "meshes" / "bun_zipper_res4.ply")
    assert main(["render", bunny, *small, "--out", str(tmp_path / "b.png")]) == 0
    _framed(np.load(npy))
    # The CT head: its face (front, -y in the file) turned to +z, the default view's side:
    # the neck, behind the face, sits at lower z than the head's middle.
    head = str(tmp_path / "ct.npz")
    ct = str(data_dir / "volumes" / "headsq" / "quarter.nhdr")
    assert main(["voxelize", ct, "--up=-z", "--resolution", "40", "--out", head]) == 0
    c = np.asarray(V.load_scene(head).coords, float)
    neck = c[c[:, 1] <= c[:, 1].min() + 0.1 * np.ptp(c[:, 1])]
    assert neck[:, 2].mean() < c[:, 2].mean() - 0.1 * np.ptp(c[:, 2])
    argv = ["render-voxels", head, "--reference", *small, "--out", str(tmp_path / "h.png")]
    assert main(argv) == 0
    _framed(np.load(npy))
    assert "warning" not in capsys.readouterr().err


# ---------------------------------------------------------------- the process around a command


def test_freed_memory_is_kept_only_on_the_cpu(tmp_path, monkeypatch):
    from jaxgfx.cli import runs_on_cpu

    assert runs_on_cpu({"JAX_PLATFORMS": "cpu"}) is True
    assert runs_on_cpu({"JAX_PLATFORMS": "cuda,cpu"}) is False
    assert runs_on_cpu({"JAX_PLATFORM_NAME": "tpu"}) is False
    calls: list = []
    monkeypatch.setattr(jaxgfx.cli, "keep_freed_memory", lambda: calls.append(1))
    monkeypatch.setattr(jaxgfx.cli, "runs_on_cpu", lambda: False)
    assert main(["--no-cache", "info"]) == 0 and calls == []
    monkeypatch.setattr(jaxgfx.cli, "runs_on_cpu", lambda: True)
    assert main(["--no-cache", "info"]) == 0 and calls == [1]


def test_compilation_cache_is_bounded(tmp_path, capsys, monkeypatch):
    from jaxgfx.cli import cache_max_bytes, prune_cache

    assert cache_max_bytes({}) == jaxgfx.cli.CACHE_MAX_MB << 20
    assert cache_max_bytes({"JAXGFX_CACHE_MAX_MB": "2.5"}) == int(2.5 * 2**20)
    assert cache_max_bytes({"JAXGFX_CACHE_MAX_MB": "0"}) == 0
    cache = tmp_path / "c"
    (cache / "sub").mkdir(parents=True)
    for k, name in enumerate(["a", "b", "sub/c", "d"]):  # a is the least recently used
        f = cache / name
        f.write_bytes(b"x" * 1000)
        os.utime(f, (1000 + k, 1000 + k))
    assert prune_cache(cache, 2500) == 2000
    left = sorted(str(p.relative_to(cache)) for p in cache.rglob("*") if p.is_file())
    assert left == ["d", "sub/c"]
    assert prune_cache(cache, 10**6) == 0


def test_cache_size_from_the_environment(capsys, cache_calls, monkeypatch):
    monkeypatch.setenv("JAXGFX_CACHE_MAX_MB", "0")  # no cache at all
    assert main(["info"]) == 0 and cache_calls == []
    capsys.readouterr()
    monkeypatch.setenv("JAXGFX_CACHE_MAX_MB", "lots")
    assert main(["info"]) == 2
    _error_line(capsys, "JAXGFX_CACHE_MAX_MB", "'lots'")
    assert cache_calls == []
